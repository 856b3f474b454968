"""The one-servo test stand: real servo logs (BAM's pendulum format), the stand simulated through
the shared servo model, how well a servo model predicts the logs, and the identification that fits
one to them (``hilbench identify`` on stand logs: fit.py, fit_errors.py, identify.py and its report),
searching with the bench's one fitting loop (bench.core.search) as the rig's identification does."""
