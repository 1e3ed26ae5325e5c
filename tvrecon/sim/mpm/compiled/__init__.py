"""The compiled backend of the solver (``MLSMPM(compile=True)``): per-particle kernels (:mod:`.kernels`), the grid
update on the block grid (:mod:`.grid`), their ``torch.compile`` wrapping (:mod:`.backend`) and the no-grad step built
from them (:mod:`.step`). On one CPU thread the step runs small C++ loops instead (built by :mod:`.cpp_loop`): P2G
(:mod:`.scatter`), G2P (:mod:`.gather`), the polar decomposition (:mod:`.polar`), the particle contact's passes
(:mod:`.contact`), the stencil bases and block index (:mod:`.stencil`) and the grid update (:mod:`.grid_loop`)."""
