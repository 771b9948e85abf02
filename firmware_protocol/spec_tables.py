"""The generated parts of ``SPEC.md``: state table, refusal table, schema text, layouts.

Each part sits in ``SPEC.md`` between ``<!-- generated:NAME -->`` and ``<!-- end:NAME -->``
markers and is written from the code's single sources (:data:`~firmware_protocol.states.
TRANSITIONS`, :func:`~firmware_protocol.schema.canonical_text`), so the SPEC cannot drift
from the implementation. Regenerate after a deliberate change with::

    python -m firmware_protocol.spec_tables --write
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from pathlib import Path

from firmware_protocol.enums import Role
from firmware_protocol.schema import canonical_text
from firmware_protocol.states import _ROWS, State, next_state

SPEC_PATH = Path(__file__).with_name("SPEC.md")

HOST_MESSAGES = ("HELLO", "CONFIGURE", "START", "STOP", "KEEPALIVE", "DAC_DATA")
"""Message kinds the host sends, in the refusal table's column order."""
DEVICE_RESTING_STATES = (State.IDLE, State.READY, State.CONFIGURED, State.STREAMING, State.STOPPED)
"""The states a device is in when a host frame arrives: it answers every command before it
reads the next frame, so it never rests in HELLO_SENT, VERSION_SENT, CONFIGURING, STARTING or
STOPPING."""


def transition_table() -> str:
    """The state table (one row per legal (states, sender, kind)) as Markdown."""
    rows = ["| in states | sender | kind | next state |", "|---|---|---|---|"]
    for states, sender, kind, target in _ROWS:
        names = ", ".join(s.value for s in states)
        rows.append(
            f"| {names} | {sender.name} | {kind} | {target.value if target else '(stays)'} |"
        )
    return "\n".join(rows)


def _answer(state: State, kind: str) -> str:
    target = next_state(state, Role.HOST, kind)
    if state is State.IDLE and target is None:
        return "ignored"
    if target is None:
        return "NAK BAD_STATE"
    replies = {
        "HELLO": "VERSION (+ CAPABILITIES)",
        "CONFIGURE": "ACK or NAK",
        "START": "ACK or NAK",
        "STOP": "ACK",
        "KEEPALIVE": "(none)",
        "DAC_DATA": "(none) or NAK",
    }
    return replies[kind]


def refusal_table() -> str:
    """What a device answers to each host message in each state it can be in, as Markdown."""
    rows = [
        "| device state | " + " | ".join(HOST_MESSAGES) + " |",
        "|---|" + "---|" * len(HOST_MESSAGES),
    ]
    for state in DEVICE_RESTING_STATES:
        cells = " | ".join(_answer(state, kind) for kind in HOST_MESSAGES)
        rows.append(f"| {state.value} | {cells} |")
    return "\n".join(rows)


def schema_block() -> str:
    """The canonical schema text (its CRC-32 is the schema hash), as a fenced block."""
    return "```text\n" + canonical_text() + "```"


GENERATORS: dict[str, Callable[[], str]] = {
    "transitions": transition_table,
    "refusals": refusal_table,
    "schema": schema_block,
}


def render(text: str) -> str:
    """``text`` (SPEC.md) with every generated section replaced by what the code generates."""
    for name, make in GENERATORS.items():
        pattern = re.compile(rf"(<!-- generated:{name} -->\n).*?(<!-- end:{name} -->)", re.DOTALL)
        if not pattern.search(text):
            raise ValueError(f"SPEC.md has no generated section {name!r}")
        body = make() + "\n"

        def fill(match: re.Match[str], body: str = body) -> str:
            return match.group(1) + body + match.group(2)

        text = pattern.sub(fill, text)
    return text


def main(argv: list[str] | None = None) -> int:
    """``--write`` regenerates SPEC.md's generated sections; ``--check`` exits 1 if stale."""
    parser = argparse.ArgumentParser(prog="python -m firmware_protocol.spec_tables")
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--write", action="store_true", help=f"rewrite {SPEC_PATH.name}")
    group.add_argument("--check", action="store_true", help="fail if a section is stale")
    args = parser.parse_args(argv)
    current = SPEC_PATH.read_text(encoding="utf-8")
    fresh = render(current)
    if args.write:
        SPEC_PATH.write_text(fresh, encoding="utf-8")
        print(f"wrote {SPEC_PATH}")
        return 0
    if fresh != current:
        print(f"{SPEC_PATH} is stale: run python -m firmware_protocol.spec_tables --write")
        return 1
    print(f"{SPEC_PATH} is up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main())
