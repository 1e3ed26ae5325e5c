"""Physics checks of the solver against contact theory (Hertz, the thin bonded layer), shared by the tests and the
benchmarks: the scenes (:mod:`.physics_checks`) and the step-and-hold schedule that reads them at rest
(:mod:`.quasi_static`). Nothing here changes the simulator."""
