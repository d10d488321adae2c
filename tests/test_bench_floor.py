"""The core benchmark's floor: the bare reads it times read every number of the clusters once."""
import numpy as np
import pytest

from benchmarks.core_benchmark import _stream, _wide_stream


@pytest.mark.parametrize("lanes", [4, 8])
@pytest.mark.parametrize("n_positions", [1, 7, 64, 129])
def test_the_wide_read_sums_every_block_entry_and_index_once(lanes, n_positions):
    """Lengths that are and are not multiples of the unrolled width: the tail must be read too."""
    rng = np.random.default_rng(n_positions)
    sh_cols = rng.integers(0, 1000, size=n_positions * lanes)
    sh_blocks = rng.normal(size=(n_positions, 9, lanes))
    bd_cols = rng.integers(0, 1000, size=4 * lanes)
    bd_blocks = rng.normal(size=(4, 9, lanes))
    exact = sh_blocks.sum() + bd_blocks.sum() + float(sh_cols.sum() + bd_cols.sum())
    for reps in (1, 3):
        wide = _wide_stream(sh_cols, sh_blocks, bd_cols, bd_blocks, reps, lanes)
        loop = _stream(sh_cols, sh_blocks, bd_cols, bd_blocks, reps)
        assert wide == pytest.approx(reps * exact, rel=1e-12)
        assert loop == pytest.approx(reps * exact, rel=1e-12)


def test_in_numba_refuses_a_threaded_build():
    """A threaded build called inside in_numba's serial loop would be inlined there and run serial
    (numba_config.PARALLEL), so the benchmark would time the wrong thing."""
    from benchmarks.core_benchmark import in_numba
    from clusterfem_ros.fem.kernels.cluster_force_kernel import force_kernel_parallel, force_kernel_serial
    with pytest.raises(ValueError, match="force_kernel.*threaded"):
        in_numba(force_kernel_parallel, (), 1)
    assert callable(in_numba(force_kernel_serial, (), 1))
