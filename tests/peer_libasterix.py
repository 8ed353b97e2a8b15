"""Decodes ASTERIX datagrams with libasterix (an independent decoder); run by its venv.

    python -I peer_libasterix.py HEX_FILE

HEX_FILE holds one datagram a line, as hex. Prints one JSON line per record:
{"cat": N, "items": {...}} with every element of every item converted to its value
(spares left out, as our codec does), for CAT062 1.21 (with REF 1.3), CAT063 1.7 and
CAT065 1.6; a record libasterix cannot parse, or a datagram with octets left over, is an
{"error": ...} line. Run with ``-I`` so that the repository's own ``asterix`` package can
never be imported instead (both are named ``asterix``).
"""

from __future__ import annotations

import importlib
import json
import sys
from typing import Any

base: Any = importlib.import_module("asterix.base")
gen: Any = importlib.import_module("asterix.generated")

SPECS = {62: gen.Cat_062_1_21, 63: gen.Cat_063_1_7, 65: gen.Cat_065_1_6}
REFS = {62: gen.Ref_062_1_3}


def value(var: Any, cat: int) -> Any:
    cls = type(var)
    if isinstance(var, base.Element):
        content = cls.cv_rule.cv_content
        if issubclass(content, base.ContentQuantity):
            return var.content.as_quantity()
        if issubclass(content, base.ContentString):
            return var.content.as_string()
        if issubclass(content, base.ContentInteger):
            return var.content.as_integer()
        return var.content.as_uint()
    if isinstance(var, base.Group):
        return {i.arg.cv_name: nonspare(i.arg, cat) for i in var.arg if isinstance(i, base.Item)}
    if isinstance(var, base.Extended):
        return {
            i.arg.cv_name: nonspare(i.arg, cat)
            for part in var.arg
            for i in part
            if isinstance(i, base.Item)
        }
    if isinstance(var, base.Repetitive):
        return [value(x, cat) for x in var.get_list()]
    if isinstance(var, base.Compound):
        return {name: nonspare(nsp, cat) for name, nsp in var.arg.items()}
    if isinstance(var, base.Explicit):
        if cls.cv_explicit_type is base.ReservedExpansion and cat in REFS:
            parsed = REFS[cat].cv_expansion.parse(base.Bits.from_bytes(var.get_bytes()))
            if isinstance(parsed, ValueError):
                raise parsed
            return {name: nonspare(nsp, cat) for name, nsp in parsed[0].arg.items()}
        return var.get_bytes().hex().upper()
    raise TypeError(f"unexpected libasterix variation {cls.__mro__}")


def nonspare(nsp: Any, cat: int) -> Any:
    rule = nsp.rule
    if isinstance(rule, base.RuleVariationContextFree) or hasattr(rule, "variation"):
        return value(rule.variation, cat)
    return value(nsp.variation, cat)


def main(path: str) -> None:
    with open(path, encoding="ascii") as lines:
        text = lines.read().splitlines()
    for line in text:
        data = bytes.fromhex(line.strip())
        blocks = base.RawDatablock.parse(base.Bits.from_bytes(data))
        if isinstance(blocks, ValueError):
            print(json.dumps({"error": f"datagram: {blocks}"}))
            continue
        for block in blocks:
            cat = block.get_category()
            records = SPECS[cat].cv_uap.parse(block.get_raw_records())
            if isinstance(records, ValueError):
                print(json.dumps({"error": f"CAT{cat:03d} block: {records}"}))
                continue
            for record in records:
                items = {name: nonspare(nsp, cat) for name, nsp in record.items_regular.items()}
                print(json.dumps({"cat": cat, "items": items}))


if __name__ == "__main__":
    main(sys.argv[1])
