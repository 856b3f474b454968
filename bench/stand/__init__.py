"""The one-servo test stand: real servo logs (BAM's pendulum format), the stand simulated through
the shared servo model, and how well a servo model predicts the logs."""
