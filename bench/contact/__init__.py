"""Seed 001's contact experiment with Zerobot: the 64-trial protocol against the CT gantry with
the 20 mm margin, and its validation against PyBullet's own contact queries."""
