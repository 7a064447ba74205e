#!/usr/bin/env python3
"""Write MCAP bags with independent writers, for imu-fsda to read.

usage: write_bags.py SPEC.json OUTDIR

SPEC.json: {"messages": [{"topic", "type", "log_time", "msg"}]} (floats tagged "f64:<bits>"),
written in the given order. Definitions come from rosbags' built-in ROS 2 Humble types.
Writes into OUTDIR:
  mcap_ros2_zstd.mcap      mcap_ros2.writer.Writer, zstd chunks (its default)
  mcap_ros2_none.mcap      mcap_ros2.writer.Writer, uncompressed chunks
  mcap_ros2_lz4.mcap       mcap_ros2.writer.Writer, lz4 chunks
  mcap_ros2_unfinished.mcap  mcap_ros2 writer whose finish() never ran (a crashed recorder):
                           small chunks flushed, no summary, no footer
  rosbags_none/            rosbags.rosbag2.Writer (version 9, storage plugin mcap), uncompressed
  rosbags_zstd/            the same with CompressionMode.STORAGE (zstd chunks)
Prints {"files": {name: path of the .mcap}}; exits 1 on any error.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from interop_common import Mismatch, dump, plain_to_rosbags, run_main, untagged


def write_mcap_ros2(path: Path, messages: list[dict], ts, compression, chunk_size: int = 1024 * 1024, finish: bool = True) -> None:
    from mcap_ros2.writer import Writer

    f = path.open('wb')
    writer = Writer(f, chunk_size=chunk_size, compression=compression)
    schemas = {}
    for seq, item in enumerate(messages):
        typename = item['type']
        if typename not in schemas:
            msgdef, _ = ts.generate_msgdef(typename, ros_version=2)
            schemas[typename] = writer.register_msgdef(typename, msgdef)
        # mcap_ros2 fills missing fields with defaults: check the field names via rosbags first.
        plain_to_rosbags(item['value'], ts, typename)
        writer.write_message(item['topic'], schemas[typename], item['value'], log_time=item['log_time'], publish_time=item['log_time'], sequence=seq)
    if finish:
        writer.finish()
    else:
        # Push out every complete chunk, as a recorder killed after its last flush leaves the file.
        writer._writer.flush()  # noqa: SLF001
    f.close()


def write_rosbags(path: Path, messages: list[dict], ts, compress: bool) -> Path:
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    if compress:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        conns = {}
        for item in messages:
            key = (item['topic'], item['type'])
            if key not in conns:
                conns[key] = writer.add_connection(item['topic'], item['type'], typestore=ts)
            data = ts.serialize_cdr(plain_to_rosbags(item['value'], ts, item['type']), item['type'], little_endian=True)
            writer.write(conns[key], item['log_time'], data)
    files = sorted(path.glob('*.mcap'))
    if len(files) != 1:
        raise Mismatch(f'rosbags wrote {files} into {path}, expected one .mcap file')
    return files[0]


def main() -> None:
    if len(sys.argv) != 3:
        raise Mismatch('usage: write_bags.py SPEC.json OUTDIR')
    from mcap.writer import CompressionType
    from rosbags.typesys import Stores, get_typestore

    with open(sys.argv[1], encoding='utf-8') as f:
        spec = json.load(f)
    out = Path(sys.argv[2])
    out.mkdir(parents=True, exist_ok=True)
    ts = get_typestore(Stores.ROS2_HUMBLE)
    messages = [{**m, 'value': untagged(m['msg'])} for m in spec['messages']]
    files = {}
    for name, comp in (('mcap_ros2_zstd', CompressionType.ZSTD), ('mcap_ros2_none', CompressionType.NONE), ('mcap_ros2_lz4', CompressionType.LZ4)):
        files[name] = out / f'{name}.mcap'
        write_mcap_ros2(files[name], messages, ts, comp)
    files['mcap_ros2_unfinished'] = out / 'mcap_ros2_unfinished.mcap'
    write_mcap_ros2(files['mcap_ros2_unfinished'], messages, ts, CompressionType.ZSTD, chunk_size=256, finish=False)
    files['rosbags_none'] = write_rosbags(out / 'rosbags_none', messages, ts, compress=False)
    files['rosbags_zstd'] = write_rosbags(out / 'rosbags_zstd', messages, ts, compress=True)
    dump({'files': {k: str(v) for k, v in files.items()}})


if __name__ == '__main__':
    run_main(main)
