"""Static PyBullet bodies of a 2D world extruded up from the ground plane (the racecar's
obstacles and regions).

Boxes become ``GEOM_BOX``, balls vertical cylinders, convex polygons one convex-hull prism and
other polygons one prism per triangle of an ear-clipping triangulation. Boxes and cylinders
share bodies, ``COMPOUND_LIMIT`` to a body: every body costs each physics step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from planner.geometry.shapes import Ball, Box, Polygon


def shape_ccw(points: list[list[float]]) -> bool:
    """True if the polygon's vertices run counter-clockwise."""
    n = len(points)
    area = sum(points[i - 1][0] * points[i][1] - points[i][0] * points[i - 1][1] for i in range(n))
    return area > 0.0


def _convex(points: list[list[float]]) -> bool:
    n = len(points)
    signs = set()
    for i in range(n):
        (ax, ay), (bx, by), (cx, cy) = points[i - 1], points[i], points[(i + 1) % n]
        cross = (bx - ax) * (cy - by) - (by - ay) * (cx - bx)
        if cross != 0.0:
            signs.add(cross > 0.0)
    return len(signs) <= 1


def triangulate(vertices: np.ndarray) -> list[tuple[int, int, int]]:
    """Ear-clipping triangulation of a simple polygon; indices into ``vertices``, CCW triangles."""
    pts: list[list[float]] = np.asarray(vertices, dtype=float).tolist()
    area = sum(pts[i - 1][0] * pts[i][1] - pts[i][0] * pts[i - 1][1] for i in range(len(pts)))
    idx = list(range(len(pts))) if area > 0.0 else list(range(len(pts)))[::-1]

    def cross(o: int, a: int, b: int) -> float:
        (ox, oy), (ax, ay), (bx, by) = pts[o], pts[a], pts[b]
        return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)

    triangles: list[tuple[int, int, int]] = []
    while len(idx) > 3:
        for k in range(len(idx)):
            i, j, m = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            turn = cross(i, j, m)
            if turn == 0.0:
                del idx[k]
                break
            if turn < 0.0:
                continue
            inside = any(
                cross(i, j, q) >= 0.0 and cross(j, m, q) >= 0.0 and cross(m, i, q) >= 0.0
                for q in idx
                if q not in (i, j, m)
            )
            if not inside:
                triangles.append((i, j, m))
                del idx[k]
                break
        else:
            raise ValueError("polygon could not be triangulated (is it simple?)")
    if len(idx) == 3 and cross(idx[0], idx[1], idx[2]) != 0.0:
        triangles.append((idx[0], idx[1], idx[2]))
    return triangles


def prism(points: list[list[float]], z0: float, z1: float) -> tuple[list[list[float]], list[int]]:
    """Vertices and triangle indices of a convex polygon (CCW) extruded from z0 to z1."""
    n = len(points)
    verts = [[x, y, z0] for x, y in points] + [[x, y, z1] for x, y in points]
    faces: list[int] = []
    for k in range(1, n - 1):
        faces += [0, k + 1, k, n, n + k, n + k + 1]
    for k in range(n):
        j = (k + 1) % n
        faces += [k, j, n + j, k, n + j, n + k]
    return verts, faces


COMPOUND_LIMIT = 16
"""Child shapes PyBullet keeps in one compound collision or visual shape (it drops the rest).
Obstacles share bodies up to this many: every body costs each physics step, and a forest of 111
balls as 111 bodies made the car's steps 1.3-2x slower (CPU time) than as 7."""
GEOMS = {"box": "GEOM_BOX", "cylinder": "GEOM_CYLINDER"}


@dataclass(frozen=True)
class Piece:
    """One static part of a 2D shape extruded up from the plane: a box, a vertical cylinder or
    a prism mesh (``vertices`` and triangle ``faces``) at ``position``."""

    kind: Literal["box", "cylinder", "mesh"]
    position: list[float]
    half_extents: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    radius: float = 0.0
    length: float = 0.0
    vertices: list[list[float]] = field(default_factory=list)
    faces: list[int] = field(default_factory=list)


def shape_pieces(shape: Any, height: float) -> list[Piece]:
    """The parts of ``shape`` extruded from 0 to ``height``: a box for a box, a vertical
    cylinder for a ball, one convex-hull prism for a convex polygon and one prism per triangle
    of its ear-clipping triangulation for another."""
    half = 0.5 * height
    if isinstance(shape, Box):
        centre = [*(0.5 * (shape.hi + shape.lo)).tolist(), half]
        return [Piece("box", centre, half_extents=[*(0.5 * (shape.hi - shape.lo)).tolist(), half])]
    if isinstance(shape, Ball):
        return [
            Piece("cylinder", [*shape.center.tolist(), half], radius=shape.radius, length=height)
        ]
    if isinstance(shape, Polygon):
        pts: list[list[float]] = shape.vertices.tolist()
        if _convex(pts):
            parts = [pts if shape_ccw(pts) else pts[::-1]]
        else:
            parts = [[pts[i], pts[j], pts[k]] for i, j, k in triangulate(shape.vertices)]
        out = []
        for part in parts:
            verts, faces = prism(part, 0.0, height)
            out.append(Piece("mesh", [0.0, 0.0, 0.0], vertices=verts, faces=faces))
        return out
    raise ValueError(f"unsupported obstacle shape {type(shape).__name__}")


def add_static_bodies(
    pb: Any, c: int, pieces: list[Piece], solid: bool, rgba: tuple[float, ...]
) -> list[int]:
    """Static bodies holding ``pieces`` in PyBullet client ``c`` (module ``pb``; collision
    shapes too if ``solid``): boxes and cylinders ``COMPOUND_LIMIT`` to a body, each mesh a body
    of its own."""
    bodies: list[int] = []
    primitives = [p for p in pieces if p.kind != "mesh"]
    for first in range(0, len(primitives), COMPOUND_LIMIT):
        group = primitives[first : first + COMPOUND_LIMIT]
        shape = {
            "shapeTypes": [getattr(pb, GEOMS[p.kind]) for p in group],
            "radii": [p.radius for p in group],
            "halfExtents": [p.half_extents for p in group],
            "lengths": [p.length for p in group],
        }
        frames = [p.position for p in group]
        col = -1
        if solid:
            col = pb.createCollisionShapeArray(
                **shape, collisionFramePositions=frames, physicsClientId=c
            )
        vis = pb.createVisualShapeArray(**shape, visualFramePositions=frames, physicsClientId=c)
        bodies.append(_static_body(pb, c, col, vis, [0.0, 0.0, 0.0], rgba))
    for mesh in (p for p in pieces if p.kind == "mesh"):
        col = -1
        if solid:
            col = pb.createCollisionShape(pb.GEOM_MESH, vertices=mesh.vertices, physicsClientId=c)
        vis = pb.createVisualShape(
            pb.GEOM_MESH, vertices=mesh.vertices, indices=mesh.faces, physicsClientId=c
        )
        bodies.append(_static_body(pb, c, col, vis, mesh.position, rgba))
    return bodies


def _static_body(
    pb: Any, c: int, col: int, vis: int, position: list[float], rgba: tuple[float, ...]
) -> int:
    body = int(
        pb.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=col,
            baseVisualShapeIndex=vis,
            basePosition=position,
            physicsClientId=c,
        )
    )
    pb.changeVisualShape(body, -1, rgbaColor=rgba, physicsClientId=c)
    return body
