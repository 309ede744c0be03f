"""Error of an estimated pairwise transform against a dsmgen truth.json.

`pair_errors(truth, est, a, b)`: est is the 4x4 p_ref = est @ p_moving that
registers tile b (moving) onto tile a (reference); the truth is
M_a^-1 M_b. Returns (worst displacement in metres over the corners of the
overlap of a chain's neighbours, at 230 m height; rotation error in degrees;
yaw error in degrees).
"""
import numpy as np


def pair_errors(truth, est, a, b):
    M = [np.array(t["matrix_world"]) for t in truth["tiles"]]
    e = np.linalg.inv(np.asarray(est)) @ (np.linalg.inv(M[a]) @ M[b])
    g0, g1 = truth["tiles"][0]["geotransform"], truth["tiles"][1]["geotransform"]
    w = truth["tiles"][0]["width"]
    xs, ys = (g1[0], g0[0] + g0[1] * w), (g0[3], g0[3] + g0[5] * w)
    worst = max(np.linalg.norm((e @ np.array([x, y, 230.0, 1]))[:3] - [x, y, 230.0])
                for x in xs for y in ys)
    ang = np.degrees(np.arccos(np.clip((np.trace(e[:3, :3]) - 1) / 2, -1, 1)))
    yaw = abs(np.degrees(np.arctan2(e[1, 0], e[0, 0])))
    return worst, ang, yaw
