"""Golden outputs: the sha256 of everything `replay` and `export lerobot --codec lossless` write for one seeded bag.

The redesign of the package (moving modules, one fan-out, one statistics
path) must not change a byte of what users get. This module makes the outputs
through the CLI, as a user would, from a seeded simulated bag of the bundled
demo rig, and reduces them to hashes:

- every message replay writes: (topic, log time, sha256 of its CDR bytes), as
  the mcap reader reads them;
- every file the export writes: its sha256, and for files a library stamps
  with its own version (parquet: `created_by`; mp4: the muxer's tag) also a
  hash of the decoded content (the parquet table, the video's decoded frames),
  so a dependency upgrade shows up as "files differ, content equal" and not as
  a change of ours. The provenance file names the source bag's absolute path
  and the gates file's path in this checkout: both are replaced (by the bag's
  name, by `<repo>`) before hashing.

`python -m test.support.golden --write` records the hashes of today's code in
test/support/golden/demo_bimanual_seed7.json; test/test_golden_outputs.py compares.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from dataclasses import asdict, dataclass
from importlib.metadata import version
from pathlib import Path

import av
import numpy as np
import pyarrow.parquet as pq
from mcap.reader import make_reader

from roi_node.cli import main as roi_node

REPO = Path(__file__).resolve().parents[2]
RIG = REPO / "config" / "rig_demo_bimanual.yaml"
GOLDEN = Path(__file__).resolve().parent / "golden" / "demo_bimanual_seed7.json"
SEED, DURATION_S, FPS, TASK = 7, 2.0, 30, "hand the cube over"
VERSIONED_LIBRARIES = ("pyarrow", "av")  # they stamp their version into the files they write


@dataclass(frozen=True)
class GoldenOutputs:
    libraries: dict[str, str]  # name -> version that wrote the files
    replay_messages: list[tuple[str, int, str]]  # (topic, log time ns, sha256 of the CDR bytes)
    export_files: dict[str, str]  # path in the dataset -> sha256 of the file
    export_content: dict[str, str]  # path -> sha256 of the decoded content (parquet tables, videos)

    @classmethod
    def from_json(cls, text: str) -> GoldenOutputs:
        doc = json.loads(text)
        return cls(doc["libraries"], [tuple(m) for m in doc["replay_messages"]], doc["export_files"], doc["export_content"])

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1, sort_keys=True) + "\n"


def make_outputs(work: Path) -> tuple[Path, Path]:
    """Sim bag -> replay -> lossless export, through the CLI; returns (replay output, dataset)."""
    sim, roi, dataset = work / "sim", work / "roi", work / "dataset"
    steps = [
        ["sim", "--config", str(RIG), "--bag", str(sim), "--duration", str(DURATION_S), "--seed", str(SEED)],
        ["replay", str(sim), "-o", str(roi), "--config", str(RIG)],
        ["export", "lerobot", str(roi), "-o", str(dataset), "--fps", str(FPS), "--codec", "lossless", "--task", TASK],
    ]
    for argv in steps:
        code = roi_node(argv)
        if code != 0:
            raise RuntimeError(f"roi-node {' '.join(argv)} exited {code}")
    return roi, dataset


def hash_outputs(roi: Path, dataset: Path) -> GoldenOutputs:
    messages = []
    for mcap_file in sorted(roi.glob("*.mcap")):
        with mcap_file.open("rb") as stream:
            for _, channel, message in make_reader(stream).iter_messages(log_time_order=True):
                messages.append((channel.topic, message.log_time, hashlib.sha256(message.data).hexdigest()))
    files, content = {}, {}
    for path in sorted(p for p in dataset.rglob("*") if p.is_file()):
        name = path.relative_to(dataset).as_posix()
        data = path.read_bytes()
        if path.name == "roi_node_provenance.json":
            data = data.replace(str(roi).encode(), roi.name.encode()).replace(str(REPO).encode(), b"<repo>")
        files[name] = hashlib.sha256(data).hexdigest()
        if path.suffix == ".parquet":
            table = pq.read_table(path)
            content[name] = hashlib.sha256(json.dumps(table.to_pylist(), sort_keys=True, default=str).encode()).hexdigest()
        elif path.suffix == ".mp4":
            content[name] = _video_content_sha256(path)
    return GoldenOutputs({lib: version(lib) for lib in VERSIONED_LIBRARIES}, messages, files, content)


def _video_content_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with av.open(str(path)) as container:
        for frame in container.decode(video=0):
            digest.update(np.ascontiguousarray(frame.to_ndarray(format="rgb24")).tobytes())
    return digest.hexdigest()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true", help=f"record today's hashes in {GOLDEN.relative_to(REPO)}")
    parser.add_argument("--work", type=Path, required=True, help="an empty folder for the bags and the dataset")
    args = parser.parse_args()
    outputs = hash_outputs(*make_outputs(args.work))
    if args.write:
        GOLDEN.parent.mkdir(exist_ok=True)
        GOLDEN.write_text(outputs.to_json())
        print(f"wrote {GOLDEN}: {len(outputs.replay_messages)} messages, {len(outputs.export_files)} files")
    return 0


if __name__ == "__main__":
    sys.exit(main())
