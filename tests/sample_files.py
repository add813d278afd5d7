"""Bundled samples with one part replaced, for the bad-input tests (catalogue and fuzz findings)."""

from __future__ import annotations

import io
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def json_positions_with_first(payload: bytes) -> bytes:
    """The bundled JSON positions sample (``replay convert mcap``'s input) with its first
    message's payload replaced by ``payload``; every other record as it was."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    messages = list(make_reader(io.BytesIO((REPO / "data/samples/json_positions.mcap").read_bytes())).iter_messages())
    out = io.BytesIO()
    w = Writer(out)
    w.start()
    schema, channel, _ = messages[0]
    sid = w.register_schema(schema.name, schema.encoding, schema.data)
    cid = w.register_channel(channel.topic, channel.message_encoding, sid, channel.metadata)
    for i, (_, _, m) in enumerate(messages):
        w.add_message(cid, m.log_time, payload if i == 0 else m.data, m.publish_time)
    w.finish()
    return out.getvalue()
