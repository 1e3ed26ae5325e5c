"""The run plumbing under ``train.py`` and ``eval.py``: Lightning callbacks (gradient norm, precise BatchNorm
statistics, warm start and freezing), the CSV history of a resumed run, and the run control (the checkpoint to resume
from, SIGTERM/Ctrl-C exit codes, the model/data check, the test split's touch count)."""
