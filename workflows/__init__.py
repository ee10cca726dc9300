"""The orchestration layer: the family build, batch generation and the service on Ray.

Ray starts its task and actor processes at niceness 15 (its ``worker_niceness``), so that its own
control processes stay responsive; on a machine whose cores are busy with other work, every task
then waits behind that work (measured: a build's cage-pair tasks got 3-4% of a core each while two
other processes kept both cores busy, and the build did not finish). The Rays this package starts,
and the nodes of ``cluster/local_cluster.sh``, run them at the driver's own priority, as the
in-process build runs; a ``RAY_worker_niceness`` set by the user wins.
"""

import os

os.environ.setdefault("RAY_worker_niceness", "0")
