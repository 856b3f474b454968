"""The CT room: URDF generation for the robots and the room, the robots' collision geometry,
contact detection against the gantry, static dynamics from the URDF, and pictures of it."""
