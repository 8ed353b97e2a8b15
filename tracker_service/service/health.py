"""What makes a container unhealthy, from the daemon's own status.

A container's health check restarts (or takes out of service) what it calls unhealthy, so
only what a restart may cure, and what leaves the service useless, counts: every radar
silent for longer than ``silent_for_s`` (no input at all: the network, the multicast
membership, the feeds), or the chain more than ``behind_s`` behind the wall clock (its
picture too late to use). One radar silent or degraded is in the status's reasons, for
the operator, but the service still serves the others' traffic: healthy.
"""

from __future__ import annotations

from tracker_service.outputs.messages import StatusMessage

__all__ = ["DEFAULT_BEHIND_S", "DEFAULT_SILENT_FOR_S", "unhealthy_reasons"]

DEFAULT_SILENT_FOR_S = 60.0
DEFAULT_BEHIND_S = 30.0


def unhealthy_reasons(
    status: StatusMessage,
    silent_for_s: float = DEFAULT_SILENT_FOR_S,
    behind_s: float = DEFAULT_BEHIND_S,
) -> list[str]:
    """Why the service is unhealthy, one line each; none while it is not."""
    reasons = []
    radars = status.radars
    if radars and not any(r.receiving for r in radars):
        heard = [r.last_reception_time for r in radars if r.last_reception_time is not None]
        silent = status.time - max(heard) if heard else status.uptime_s
        if silent > silent_for_s:
            what = "since start" if not heard else f"for {silent:.0f} s"
            reasons.append(
                f"every radar silent {what} (more than {silent_for_s:g} s): check the "
                "network, the multicast groups and the feeds"
            )
    if status.lag_s is not None and status.lag_s > behind_s:
        reasons.append(
            f"the chain is {status.lag_s:.1f} s behind the wall clock (more than "
            f"{behind_s:g} s): overloaded"
        )
    return reasons
