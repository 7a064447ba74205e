#!/usr/bin/env python3
"""Check an MCAP bag written by imu-fsda against two independent implementations.

usage: check_bag.py BAG.mcap

* `mcap` (seeking and linear readers, CRCs validated): header profile `ros2`, every
  channel has a `ros2msg` schema and `cdr` encoding, the summary has a Statistics record
  whose counts and times match the messages actually present, every payload starts with
  the CDR little-endian encapsulation header.
* `mcap_ros2.decoder.DecoderFactory` decodes every message using the bag's own schema text;
  the same schema text drives `mcap_ros2`'s encoder, whose bytes must equal the payload.
* `rosbags`: AnyReader opens the single .mcap file, builds its types from the bag's schema
  text, and each message is deserialized and re-serialized (both with those types and with
  rosbags' built-in ROS 2 Humble types); the bytes must equal the payload. The schema text
  must parse to the same field definitions as rosbags' built-in Humble types.
* The mcap_ros2 and rosbags decodings must agree value for value (floats bit-exactly).

Prints one JSON object (floats tagged as "f64:<bits>"); exits 1 with a message on any mismatch.
"""

from __future__ import annotations

import sys
from pathlib import Path

from interop_common import Mismatch, dump, rosbags_to_plain, run_main, slots_to_plain, tagged

CDR_LE = bytes([0, 1, 0, 0])


def check(cond: bool, msg: str) -> None:
    if not cond:
        raise Mismatch(msg)


def read_with_mcap(path: Path) -> dict:
    from mcap.reader import NonSeekingReader, make_reader
    from mcap_ros2._dynamic import serialize_dynamic
    from mcap_ros2.decoder import DecoderFactory

    with path.open('rb') as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        check(summary is not None, 'no summary section')
        seeking = [
            (m.sequence, m.log_time, m.publish_time, ch.topic, bytes(m.data), dec)
            for _, ch, m, dec in reader.iter_decoded_messages(log_time_order=False)
        ]
    with path.open('rb') as f:
        linear = [
            (m.sequence, m.log_time, m.publish_time, ch.topic, bytes(m.data))
            for _, ch, m in NonSeekingReader(f, validate_crcs=True).iter_messages()
        ]

    check(header.profile == 'ros2', f'header profile is {header.profile!r}, expected "ros2"')
    schemas = summary.schemas
    channels = summary.channels
    for ch in channels.values():
        check(ch.schema_id != 0, f'channel {ch.topic}: no schema (schema_id 0)')
        check(ch.schema_id in schemas, f'channel {ch.topic}: schema {ch.schema_id} not in summary')
        sch = schemas[ch.schema_id]
        check(sch.encoding == 'ros2msg', f'schema {sch.name}: encoding {sch.encoding!r}, expected "ros2msg"')
        check(ch.message_encoding == 'cdr', f'channel {ch.topic}: message encoding {ch.message_encoding!r}, expected "cdr"')

    stats = summary.statistics
    check(stats is not None, 'summary has no Statistics record')
    check(len(seeking) == len(linear), f'seeking reader saw {len(seeking)} messages, linear reader {len(linear)}')
    check(sorted(s[:5] for s in seeking) == sorted(linear), 'seeking (chunk-index) and linear readers disagree')
    counts: dict[int, int] = {}
    by_topic = {ch.topic: cid for cid, ch in channels.items()}
    for _, _, _, topic, _ in linear:
        counts[by_topic[topic]] = counts.get(by_topic[topic], 0) + 1
    check(stats.message_count == len(linear), f'Statistics.message_count {stats.message_count} != {len(linear)} messages')
    check(
        {k: v for k, v in stats.channel_message_counts.items() if v} == counts,
        f'Statistics.channel_message_counts {stats.channel_message_counts} != counted {counts}',
    )
    check(stats.schema_count == len(schemas), f'Statistics.schema_count {stats.schema_count} != {len(schemas)}')
    check(stats.channel_count == len(channels), f'Statistics.channel_count {stats.channel_count} != {len(channels)}')
    if linear:
        lo, hi = min(m[1] for m in linear), max(m[1] for m in linear)
        check(
            (stats.message_start_time, stats.message_end_time) == (lo, hi),
            f'Statistics times {(stats.message_start_time, stats.message_end_time)} != messages {(lo, hi)}',
        )
    check(stats.chunk_count == len(summary.chunk_indexes), f'Statistics.chunk_count {stats.chunk_count} != {len(summary.chunk_indexes)} chunk indexes')

    # mcap_ros2's encoder, driven by the bag's own schema text, must reproduce every payload.
    encoders = {}
    for sch in schemas.values():
        encoders[sch.name] = serialize_dynamic(sch.name, sch.data.decode())[sch.name]
    type_of_topic = {ch.topic: schemas[ch.schema_id].name for ch in channels.values()}
    messages = []
    for seq, log_time, publish_time, topic, data, decoded in seeking:
        typename = type_of_topic[topic]
        check(data[:4] == CDR_LE, f'{topic} seq {seq}: encapsulation {data[:4].hex()} is not CDR little endian 00010000')
        again = bytes(encoders[typename](decoded))
        check(again == data, f'{topic} seq {seq}: mcap_ros2 re-encoding differs:\n  ours   {data.hex()}\n  mcap_ros2 {again.hex()}')
        messages.append({
            'sequence': seq, 'log_time': log_time, 'publish_time': publish_time, 'topic': topic,
            'type': typename, 'cdr_hex': data.hex(), 'msg': tagged(slots_to_plain(decoded)),
        })
    messages.sort(key=lambda m: m['sequence'])
    return {
        'header': {'profile': header.profile, 'library': header.library},
        'schemas': [{'id': s.id, 'name': s.name, 'encoding': s.encoding, 'data': s.data.decode()} for s in schemas.values()],
        'channels': [
            {'id': c.id, 'topic': c.topic, 'schema_id': c.schema_id, 'message_encoding': c.message_encoding, 'metadata': c.metadata}
            for c in channels.values()
        ],
        'statistics': {
            'message_count': stats.message_count,
            'schema_count': stats.schema_count,
            'channel_count': stats.channel_count,
            'chunk_count': stats.chunk_count,
            'message_start_time': stats.message_start_time,
            'message_end_time': stats.message_end_time,
            'channel_message_counts': {channels[k].topic: v for k, v in stats.channel_message_counts.items()},
        },
        'messages': messages,
    }


def read_with_rosbags(path: Path) -> list[dict]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    humble = get_typestore(Stores.ROS2_HUMBLE)
    out = []
    with AnyReader([path]) as reader:
        ts = reader.typestore
        # The bag's schema text must describe exactly the standard ROS 2 types.
        for typename, (consts, fields) in ts.fielddefs.items():
            if typename in humble.fielddefs:
                check(
                    (consts, fields) == humble.fielddefs[typename],
                    f'schema text for {typename} parses to {(consts, fields)}, ROS 2 Humble has {humble.fielddefs[typename]}',
                )
        counted: dict[int, int] = {}
        for conn, timestamp, raw in reader.messages():
            raw = bytes(raw)
            counted[conn.id] = counted.get(conn.id, 0) + 1
            for name, store in (('bag schema', ts), ('ROS 2 Humble', humble)):
                msg = store.deserialize_cdr(raw, conn.msgtype)
                again = bytes(store.serialize_cdr(msg, conn.msgtype))
                check(
                    again == raw,
                    f'{conn.topic} @ {timestamp}: rosbags ({name} types) re-serialization differs:\n  ours    {raw.hex()}\n  rosbags {again.hex()}',
                )
            plain = rosbags_to_plain(humble.deserialize_cdr(raw, conn.msgtype), humble, conn.msgtype)
            out.append({'topic': conn.topic, 'type': conn.msgtype, 'timestamp': timestamp, 'cdr_hex': raw.hex(), 'msg': tagged(plain)})
        for conn in reader.connections:
            check(conn.msgcount == counted.get(conn.id, 0), f'rosbags: {conn.topic} msgcount {conn.msgcount} from the summary, {counted.get(conn.id, 0)} read')
    return out


def main() -> None:
    if len(sys.argv) != 2:
        raise Mismatch('usage: check_bag.py BAG.mcap')
    path = Path(sys.argv[1])
    result = read_with_mcap(path)
    rb = read_with_rosbags(path)
    check(len(rb) == len(result['messages']), f'rosbags read {len(rb)} messages, mcap {len(result["messages"])}')
    # Both libraries must see the same payloads and decode them to the same values.
    key = lambda m: m['cdr_hex']  # noqa: E731
    by_mcap = sorted(result['messages'], key=lambda m: (m['log_time'], m['cdr_hex']))
    by_rosbags = sorted(rb, key=lambda m: (m['timestamp'], m['cdr_hex']))
    for a, b in zip(by_mcap, by_rosbags):
        check(key(a) == key(b) and a['topic'] == b['topic'] and a['log_time'] == b['timestamp'], f'mcap and rosbags disagree on message {a["topic"]} @ {a["log_time"]}')
        check(a['msg'] == b['msg'], f'{a["topic"]} @ {a["log_time"]}: mcap_ros2 decoded {a["msg"]}, rosbags decoded {b["msg"]}')
    result['rosbags_checked'] = len(rb)
    dump(result)


if __name__ == '__main__':
    run_main(main)
