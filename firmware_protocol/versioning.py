"""Version negotiation: the same major version and schema hash are required; minors may differ.

A later minor version only appends fields to payloads and adds message types sent with the
OPTIONAL flag, so a peer of another minor version is accepted: it ignores what it does not
know. A peer of another major version, or one built from other definitions (other schema
hash), is refused with a message that names both sides' values and what to do.
"""

from __future__ import annotations


def incompatibility(
    *,
    host_version: tuple[int, int],
    host_schema: int,
    board_version: tuple[int, int],
    board_schema: int,
) -> str | None:
    """Why the host and board cannot talk, or None if they can.

    >>> import textwrap
    >>> print(textwrap.fill(incompatibility(host_version=(1, 0), host_schema=0x1234,
    ...                     board_version=(2, 1), board_schema=0x5678) or "", 88))
    board speaks protocol 2.1 (schema 0x00005678), host speaks 1.0 (schema 0x00001234): the
    major versions differ; update the host software to one that speaks protocol 2.x, or
    flash firmware built for protocol 1.x
    >>> incompatibility(host_version=(1, 0), host_schema=7, board_version=(1, 3), board_schema=7)
    """
    board = f"{board_version[0]}.{board_version[1]} (schema 0x{board_schema:08x})"
    host = f"{host_version[0]}.{host_version[1]} (schema 0x{host_schema:08x})"
    if board_version[0] != host_version[0]:
        return (
            f"board speaks protocol {board}, host speaks {host}: the major versions differ;"
            f" update the host software to one that speaks protocol {board_version[0]}.x,"
            f" or flash firmware built for protocol {host_version[0]}.x"
        )
    if board_schema != host_schema:
        return (
            f"board speaks protocol {board}, host speaks {host}: same major version but the"
            " message definitions differ (schema hash mismatch), so the firmware was built"
            " from other definitions; flash firmware built from this host's"
            f" firmware_protocol/SPEC.md (schema 0x{host_schema:08x}), or install the host"
            " software the firmware was built against"
        )
    return None
