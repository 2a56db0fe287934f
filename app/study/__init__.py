"""The paper's simulation study, pure: the planar world and its trials (`planar`), the batched
simulation (`batch`), per-trajectory results (`results`) and the summary over trajectories
(`summary`); running it over processes (`run`), the sweep over worlds (`sweep`), its report
(`report`) and its figures (`figures`); `dsteleop sim` is app/cli/sim.py."""
