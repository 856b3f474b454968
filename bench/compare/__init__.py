"""Simulated against real tracking: the paper's Fig. 12 profiles, lag, RMS error and needle-tip
deviation of two sets of trial logs, the session that runs both sides, and its report."""
