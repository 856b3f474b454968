"""Collision meshes kept on disk between commands: the same meshes as made afresh, a second command
that never loads trimesh, a changed mesh file or a damaged cache file made again, and a folder that
cannot be written leaving the command working."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.geometry import shape_cache
from bench.geometry.urdf_shapes import CollisionShape, parse_collisions
from bench.scene.room import gantry_mesh

REPO = Path(__file__).resolve().parents[1]
ARC_URDF = REPO / "urdf" / "arc_train.urdf"


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    return tmp_path / "needle-hil-bench" / "shapes"


def _shapes() -> list[CollisionShape]:
    return [s for shapes in parse_collisions(ARC_URDF).values() for s in shapes]


def test_kept_meshes_are_the_meshes_made_afresh(cache):
    made = [s._make_mesh() for s in _shapes()]
    first = [s.local_mesh() for s in _shapes()]  # made and kept
    assert len(list(cache.glob("*.npz"))) == len({shape_cache.mesh_key(s.kind, s.size, s.scale, s.mesh_file)
                                                   for s in _shapes()})
    kept = [s.local_mesh() for s in _shapes()]  # read back
    for (v0, f0), (v1, f1), (v2, f2) in zip(made, first, kept):
        assert np.array_equal(v0, v1) and np.array_equal(v0, v2)
        assert np.array_equal(f0, f1) and np.array_equal(f0, f2)
    v, f = gantry_mesh()
    assert np.array_equal(gantry_mesh()[0], v) and len(f) == 2 * 96 * 32


def test_a_second_command_builds_the_interlocks_without_loading_trimesh(cache):
    code = ("import sys\nfrom bench.config.models import load_trial_config\nfrom bench.trial.plan import prepare\n"
            f"prepare(load_trial_config({str(REPO / 'hil_configs' / 'sim_target1.yaml')!r}))\n"
            "print('trimesh' in sys.modules)")
    env = {**os.environ, "XDG_CACHE_HOME": str(cache.parents[1])}
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
            for _ in range(2)]
    assert [r.returncode for r in runs] == [0, 0], runs[0].stderr + runs[1].stderr
    assert [r.stdout.strip() for r in runs] == ["True", "False"]


def test_a_changed_mesh_file_or_a_damaged_cache_file_is_made_again(cache, tmp_path):
    mesh = tmp_path / "block.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    shape = CollisionShape("mesh", (), np.eye(4), mesh)
    v1, _ = shape.local_mesh()
    mesh.write_text(mesh.read_text().replace("v 1 0 0", "v 2 0 0"))
    v2, _ = shape.local_mesh()
    assert v1[:, 0].max() == 1.0 and v2[:, 0].max() == 2.0
    for kept in cache.glob("*.npz"):
        kept.write_bytes(b"not a mesh")
    v3, f3 = shape.local_mesh()
    assert np.array_equal(v3, v2) and len(f3) == 4
    faces_out_of_range = {"vertices": v3, "faces": np.full((4, 3), 99)}
    key = shape_cache.mesh_key("mesh", (), (1.0, 1.0, 1.0), mesh)
    with open(cache / f"{key}.npz", "wb") as f:
        np.savez(f, **faces_out_of_range)
    assert np.array_equal(shape.local_mesh()[1], f3)


def test_a_cache_folder_that_cannot_be_written_leaves_the_meshes_made(tmp_path, monkeypatch):
    blocked = tmp_path / "file-not-folder"
    blocked.write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocked))
    shape = _shapes()[0]
    v, f = shape.local_mesh()
    assert np.array_equal(v, shape._make_mesh()[0]) and len(f)
