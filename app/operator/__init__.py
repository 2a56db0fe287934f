"""Simulated operators: a person's hand without a camera, for the study, the demo and tests.

open_loop    a sampled goal-directed trajectory that does not watch the robot (the
             paper's simulation, Fig. 5/6)
"""
