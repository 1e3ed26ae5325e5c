"""Pre-generating data presets: the worker pool (what the datamodules and ``python -m tvrecon.data.generate`` call),
the command's own arguments, and its shards as the jobs of a Hydra launcher (``--multirun``)."""
