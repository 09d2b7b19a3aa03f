"""Physics and numerics, arrays in and arrays out (no files, sockets, clocks or HTTP).

    types.py   the typed values that cross package boundaries (stream records, Cycle)
    model/     the one engine model: spec, kinematics, drive train, loss-term and effect libraries, EngineModel
    plant/     the time-domain simulator built from a model
    monitor/   per-cycle identification of the model's losses from tooth times and pressures

    numba_cache.py  where the compiled kernels are kept: one folder per version of the sources, set here, before any
                    kernel is decorated (numba alone would not see a changed callee in another file); and Python's
                    garbage collector paused while numba compiles (~3.4 s of a cold compile, design note 67); LLVM's
                    -O1 unless NUMBA_OPT is set (~9 % of the cold compile, the same figures, design note 98); each
                    cached kernel in a file named by its key, so two processes compiling into one folder at once
                    cannot pair one signature with another's code (design note 150)
"""

from frictionwatch.core.numba_cache import (
    name_cache_entries_by_key,
    pause_gc_while_compiling,
    use_fingerprinted_cache,
    use_optimisation_level,
)

use_optimisation_level()  # first: numba re-reads its whole environment when it changes (config.CACHE_DIR too)
use_fingerprinted_cache()
pause_gc_while_compiling()
name_cache_entries_by_key()  # before any kernel is cached: two processes may compile into one folder at once
