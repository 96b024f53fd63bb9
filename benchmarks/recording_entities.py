"""Where a recording's bytes go: KB per frame of each entity in the file, and how many chunks carry it.

    python -m benchmarks.recording_entities run.rrd [more.rrd …] [--top 14]

The bytes in the file of an entity are the file's size less the size of the same file without it (`rerun rrd
filter --drop-entity`): its rows after Rerun's LZ4, with the ~1.2 KB every chunk costs (schema and metadata,
measured: a chunk of 10 scalar rows is ~1.5 KB in the file). The `top` largest entities (by Arrow bytes) are
measured one by one; the rest are summed as "the other N entities" (file size less static data less the ones
measured). Frames are the rows of `/world/camera` (one per frame the run recorded).
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from collections import Counter
from pathlib import Path

from rerun.chunk import RrdReader


def _without(path: Path, entity: str, folder: Path) -> int:
    """Bytes of the file with `entity` dropped."""
    out = folder / "dropped.rrd"
    subprocess.run(["rerun", "rrd", "filter", str(path), "--drop-entity", entity, "-o", str(out)], check=True,
                   capture_output=True)
    return out.stat().st_size


def breakdown(path: Path, top: int = 14) -> tuple[int, list[tuple[str, float, int]], float, int, float]:
    """(frames, [(entity, KB per frame in the file, chunks)…] of the `top` largest, KB per frame of the other
    per-frame entities, how many they are, KB of static data)."""
    arrow: Counter[str] = Counter()
    chunks: Counter[str] = Counter()
    static = 0
    frames = 0
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        entity = str(chunk.entity_path)
        if chunk.is_static:
            static += batch.nbytes
            continue
        arrow[entity] += batch.nbytes
        chunks[entity] += 1
        frames += chunk.num_rows if entity == "/world/camera" else 0
    size = path.stat().st_size
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for entity, _ in arrow.most_common(top):
            rows.append((entity, (size - _without(path, entity, Path(folder))) / 1024 / frames, chunks[entity]))
    measured = sum(kb for _, kb, _ in rows)
    others = (size - static) / 1024 / frames - measured
    return frames, rows, others, len(arrow) - len(rows), static / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("recordings", type=Path, nargs="+")
    parser.add_argument("--top", type=int, default=14, help="entities measured one by one")
    args = parser.parse_args()
    for path in args.recordings:
        frames, rows, others, count, static = breakdown(path, args.top)
        print(f"{path.name}: {path.stat().st_size / 1024 / frames:.1f} KB/frame over {frames} frames "
              f"(static data {static:.0f} KB)")
        print("| entity | KB/frame in the file | chunks |")
        print("|---|---|---|")
        for entity, kb, n in rows:
            print(f"| `{entity}` | {kb:.2f} | {n} |")
        print(f"| the other {count} entities (series, events, poses) | {others:.2f} | |")


if __name__ == "__main__":
    main()
