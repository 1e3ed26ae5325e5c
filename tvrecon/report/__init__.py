"""The top layer: the paper's tables, per-class classification reports, summaries over seeds, figures of runs and
the run folders of ``train.py`` / ``eval.py``."""
