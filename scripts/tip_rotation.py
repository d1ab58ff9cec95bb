#!/usr/bin/env python3
"""Rotation of part of a body in a VTU frame written by `crokf-verify simulate --vtu`: the
best-fit (Kabsch) rotation taking the rest positions of the selected nodes to their displaced
positions, as an angle in degrees (needs NumPy).

    python3 scripts/tip_rotation.py DIR/frames/frame_0012.vtu --above-z 0.2

Nodes are selected by their rest position (the frame's points) above a height; the frame must
hold a point array named `displacement` (ASCII, as crokf-verify writes it).
"""

import argparse
import math
import re
import sys

import numpy as np


def read_frame(path):
    """Rest positions (N × 3) and displacements (N × 3) of an ASCII VTU frame."""
    try:
        text = open(path).read()
    except OSError as e:
        raise SystemExit(f"{path}: {e.strerror}")
    points = re.search(r"<Points>\s*<DataArray[^>]*>(.*?)</DataArray>", text, re.S)
    disp = re.search(r'<DataArray[^>]*Name="displacement"[^>]*>(.*?)</DataArray>', text, re.S)
    if points is None or disp is None:
        raise SystemExit(f"{path}: no <Points> or no point array 'displacement' (ASCII) found")
    try:
        x = np.array(points.group(1).split(), dtype=float).reshape(-1, 3)
        u = np.array(disp.group(1).split(), dtype=float).reshape(-1, 3)
    except ValueError as e:
        raise SystemExit(f"{path}: {e}")
    if x.shape != u.shape:
        raise SystemExit(f"{path}: {len(x)} points but {len(u)} displacements")
    return x, u


def best_fit_rotation(a, b):
    """The rotation R minimising Σ‖R aᵢ − bᵢ‖² over centred point sets (Kabsch)."""
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("frame", help="a VTU frame of crokf-verify simulate --vtu")
    parser.add_argument("--above-z", type=float, required=True,
                        help="select the nodes whose rest z is above this height (m)")
    args = parser.parse_args()
    x, u = read_frame(args.frame)
    picked = x[:, 2] > args.above_z
    if picked.sum() < 3:
        raise SystemExit(f"{args.frame}: {picked.sum()} nodes above z = {args.above_z} m; "
                         "a rotation needs at least 3")
    r = best_fit_rotation(x[picked], (x + u)[picked])
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0))))
    print(f"{args.frame}: {picked.sum()} nodes above z = {args.above_z} m, rotation {angle:.1f}°")


if __name__ == "__main__":
    sys.exit(main())
