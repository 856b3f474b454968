"""Geometry kernels for contact detection: triangle distances, a bounding-volume tree,
the analytic torus, and triangle meshes of URDF collision shapes (all numpy)."""
