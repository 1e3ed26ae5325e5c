"""The compiled backend of the solver (``MLSMPM(compile=True)``): per-particle kernels (:mod:`.kernels`), the grid
update on the block grid (:mod:`.grid`), the C++ P2G scatter (:mod:`.scatter`), their ``torch.compile`` wrapping
(:mod:`.backend`) and the no-grad step built from them (:mod:`.step`)."""
