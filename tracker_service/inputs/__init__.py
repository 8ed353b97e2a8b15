"""Live inputs of the service: radar feeds over UDP."""
