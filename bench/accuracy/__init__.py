"""Accuracy assessment of a robot's needle placement: servo tolerances through the kinematics
(Jacobian budget, Monte Carlo), Table 3 of seed 000 beside it, and its report."""
