"""pybullet"""
