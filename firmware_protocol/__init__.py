"""The wire protocol between the host and the transducer board: bytes in, events out.

No I/O anywhere in this package; see ``SPEC.md`` beside this file.
"""
