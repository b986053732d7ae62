"""Peer of tests/people.rs: pyarrow reads the people benchmark's episodes as one
Hive-partitioned dataset (episodes/row=.../method=.../episodes.parquet), as a user's analysis would,
and checks each cell's success rate and mean discomfort against benchmark.json.

usage: benchmark.py OUT   (the folder `flowgate plan --benchmark` wrote)
"""

import json
import math
import sys
from pathlib import Path

import pyarrow.compute as pc
import pyarrow.dataset as ds


def fail(why):
    print(f"people peer: {why}", file=sys.stderr)
    sys.exit(1)


def main(out):
    out = Path(out)
    table = ds.dataset(out / "episodes", format="parquet", partitioning="hive").to_table()
    report = json.loads((out / "benchmark.json").read_text())
    cells = report["cells"]
    if table.num_rows != report["episodes"] * len(cells):
        fail(f"{table.num_rows} episodes, expected {report['episodes']} in each of {len(cells)} cells")
    for cell in cells:
        row = cell["row"].replace(" ", "_").replace(",", "_")
        mine = table.filter(pc.and_(pc.equal(table["row"], row), pc.equal(table["method"], cell["method"])))
        if mine.num_rows != report["episodes"]:
            fail(f"{row}/{cell['method']}: {mine.num_rows} episodes")
        goals = pc.sum(pc.equal(mine["outcome"], "goal")).as_py() or 0
        if goals != cell["success"]["count"]:
            fail(f"{row}/{cell['method']}: {goals} at the goal, the table says {cell['success']['count']}")
        discomfort = pc.mean(mine["discomfort"]).as_py()
        if not math.isclose(discomfort, cell["discomfort"]["mean"], rel_tol=1e-9, abs_tol=1e-12):
            fail(f"{row}/{cell['method']}: discomfort {discomfort}, the table says {cell['discomfort']['mean']}")
    print(f"pyarrow read {table.num_rows} episodes in {len(cells)} cells, each as the table says")


if __name__ == "__main__":
    main(*sys.argv[1:])
