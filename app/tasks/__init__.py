"""Shared machinery for running work, used by the study, the sweep and tuning alike (neither
imports the other's): executors of tasks (`executor`: the seam, one in this process; `cluster`:
Ray tasks on a local or remote cluster, the one module that imports Ray), the errors of tasks,
and the terminal progress bar the commands share (`progress`)."""
