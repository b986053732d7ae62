"""Peer of tests/sweeps.rs: pyarrow reads a merged sweep's episodes.parquet as a user's
analysis would, and checks it against the sweep run in one piece and against its shards.

usage: sweeps.py MERGED WHOLE SHARD...   (each a folder `flowgate plan` wrote)
       sweeps.py --k8s JOB.yaml           (prints the Indexed Job's shards and command as JSON)
"""

import json
import math
import sys
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

COLUMNS = {
    "index": pa.uint64(),
    "seed": pa.uint64(),
    "outcome": pa.string(),
    "min_clearance": pa.float64(),
    "min_wall_clearance": pa.float64(),
    "duration": pa.float64(),
    "path_length": pa.float64(),
    "speed_ratio": pa.float64(),
    "delay": pa.float64(),
    "active_contact": pa.bool_(),
    "discomfort": pa.float64(),
}


def fail(why):
    print(f"sweeps peer: {why}", file=sys.stderr)
    sys.exit(1)


def read(folder):
    table = pq.read_table(Path(folder) / "episodes.parquet")
    got = {f.name: f.type for f in table.schema}
    if got != COLUMNS:
        fail(f"{folder}: columns {got}, expected {COLUMNS}")
    manifest = json.loads(table.schema.metadata[b"flowgate.manifest"])
    if manifest["episodes"] != table.num_rows:
        fail(f"{folder}: {table.num_rows} rows, the manifest says {manifest['episodes']}")
    return table, manifest


def kubernetes(path):
    import yaml

    job = yaml.safe_load(Path(path).read_text())
    if job["apiVersion"] != "batch/v1" or job["kind"] != "Job":
        fail(f"{path}: not a batch/v1 Job")
    spec = job["spec"]
    (container,) = spec["template"]["spec"]["containers"]
    print(json.dumps({
        "completion_mode": spec["completionMode"],
        "completions": spec["completions"],
        "parallelism": spec["parallelism"],
        "restart_policy": spec["template"]["spec"]["restartPolicy"],
        "command": container["command"],
        "mounts": [m["mountPath"] for m in container.get("volumeMounts", [])],
    }))


def main():
    if sys.argv[1] == "--k8s":
        return kubernetes(sys.argv[2])
    merged_dir, whole_dir, *shard_dirs = sys.argv[1:]
    merged, manifest = read(merged_dir)
    whole, whole_manifest = read(whole_dir)
    n = merged.num_rows
    if manifest != whole_manifest or manifest["shard"] != {"index": 0, "count": 1} or manifest["sweep_episodes"] != n:
        fail(f"merged manifest {manifest}, whole {whole_manifest}")
    if merged.column("index").to_pylist() != list(range(n)):
        fail("the merged episodes are not every index once, in order")
    if set(merged.column("seed").to_pylist()) != {manifest["seed"]}:
        fail("a row's seed is not the sweep's")
    if not merged.equals(whole):
        fail("the merged episodes differ from the whole sweep's")
    shards = [read(d)[0] for d in shard_dirs]
    joined = pa.concat_tables(shards).sort_by("index")
    if not joined.equals(merged):
        fail("the shards' episodes together are not the merged ones")

    report = json.loads((Path(merged_dir) / "sweep.json").read_text())
    goals = pc.sum(pc.equal(merged.column("outcome"), "goal")).as_py() or 0
    if not math.isclose(report["goal_rate"], goals / n, abs_tol=1e-12):
        fail(f"goal rate {report['goal_rate']} in sweep.json, {goals}/{n} in the episodes")
    lowest = pc.min(merged.column("min_clearance")).as_py()
    if not math.isclose(report["clearance_min"], lowest, abs_tol=1e-12):
        fail(f"least clearance {report['clearance_min']} in sweep.json, {lowest} in the episodes")
    if min(merged.column("duration").to_pylist()) <= 0:
        fail("an episode without a duration")
    print(f"pyarrow read {n} episodes: every index once, as the whole sweep's and the shards'; goal {goals}/{n}")


main()
