"""Re-write an MCAP recording with Python's own `mcap` writer, as other tools would.

Usage: rewrite_recording.py IN.mcap OUT.mcap COMPRESSION   (zstd, lz4 or none)

Every schema, channel, message and metadata record is copied; the chunks are the Python
writer's, compressed as asked (its default is zstd when `zstandard` is installed).
"""
import sys

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

source, target, compression = sys.argv[1], sys.argv[2], sys.argv[3]
kind = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression]
with open(source, "rb") as f_in, open(target, "wb") as f_out:
    reader = make_reader(f_in)
    header = reader.get_header()
    summary = reader.get_summary()
    writer = Writer(f_out, compression=kind)
    writer.start(profile=header.profile, library="python mcap (flowgate test)")
    schema_ids, channel_ids = {}, {}
    for sid, s in summary.schemas.items():
        schema_ids[sid] = writer.register_schema(s.name, s.encoding, s.data)
    for cid, c in summary.channels.items():
        channel_ids[cid] = writer.register_channel(c.topic, c.message_encoding, schema_ids[c.schema_id], c.metadata)
    for m in reader.iter_metadata():
        writer.add_metadata(m.name, m.metadata)
    for _schema, channel, message in reader.iter_messages(log_time_order=False):
        writer.add_message(
            channel_ids[channel.id], message.log_time, message.data, message.publish_time, message.sequence
        )
    writer.finish()
