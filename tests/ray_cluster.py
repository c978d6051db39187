"""A Ray cluster of several nodes on this machine, on loopback only, for the tests.

    python tests/ray_cluster.py TEMP_DIR NODES

starts a head and NODES - 1 more nodes of one CPU each (``ray.cluster_utils.Cluster``: each node its
own raylet, as separate machines would have), every one on 127.0.0.1 with the runner's loopback
environment (no usage statistics, proxies pointed at a closed port, no dashboard) and its files
under TEMP_DIR; prints one JSON line {address, nodes: [node addresses]}, then waits until its
standard input closes (the test is done, or died) and shuts every node down. It never runs
``ray stop`` (machine-wide). Kept out of the test process so that Ray's global state stays out of it.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from runners.executors import RAY_LOOPBACK_ENV  # noqa: E402


def main(temp_dir: str, nodes: int) -> None:
    os.environ.update(RAY_LOOPBACK_ENV)
    os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"  # else Ray guesses the node address from a UDP connect
    os.environ["RAY_TMPDIR"] = temp_dir
    from ray.cluster_utils import Cluster

    # Ray writes the address of the latest cluster to RAY_TMPDIR/ray; the nodes' sessions go there too
    local = {"node_ip_address": "127.0.0.1", "temp_dir": os.path.join(temp_dir, "ray"), "num_cpus": 1}
    cluster = Cluster(initialize_head=True, head_node_args={**local, "include_dashboard": False})
    try:
        for _ in range(nodes - 1):
            cluster.add_node(**local)
        cluster.wait_for_nodes()
        addresses = [node.node_ip_address for node in cluster.list_all_nodes()]
        print(json.dumps({"address": cluster.address, "nodes": addresses}), flush=True)
        sys.stdin.read()  # until the test closes it
    finally:
        cluster.shutdown()


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]))
