"""Hyper-parameter studies of the arbitration (`dsteleop tune`, app/cli/tune.py): the search
space (`space`), the objective (`objective`), the trial functions (`trial`, plain Python), the
Optuna driver (`driver`), the Ray executor (`cluster`, the only module that imports Ray), the
held-out comparison (`holdout`), the outputs (`report`, `figures`)."""
