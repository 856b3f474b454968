"""Kinematics of the robots the bench models (seed 000's arc-and-train robot, seed 001's Zerobot,
seed 003's parallel robot): DH chains, needle poses, inverse kinematics and the robot registry."""
