"""The common root of the package's errors: ``except ClusterFemError`` catches every error the package raises
on purpose (bad configuration, mesh, skeleton, motion file, measured points, an unstable or diverged step).

Each error also keeps the builtin base it had (ValueError for bad input, RuntimeError for a step that cannot
go on), so callers' ``except ValueError`` / ``except RuntimeError`` clauses keep working. Every message names
the bad value and the way out. Imports nothing: any module of the package may import it.
"""


class ClusterFemError(Exception):
    """Base of every error clusterfem_ros raises on purpose; the message names the value and the way out."""
