#!/usr/bin/env python3
"""Scores each submap of a run's largest merged map against the ground truth, to find where a merged map bends.

Aligns all merged keyframes (keyframes_merged.tsv) to the ground truth with one similarity
(Horn's closed form), then prints per submap: its keyframes, its scale relative to the whole
map's (each submap aligned alone), its position residual in the map, and the mean error of its
cameras' attitude about the ground truth's x, y and z axes. With --per-keyframe also every
keyframe's attitude error about --axis: a merged map that is right holds each submap's attitude
error steady and the same from one submap to the next; a step between two submaps is a bend at
their junction.

usage: tools/submap-attitude.py RUN_DIR [--gt FILE] [--per-keyframe] [--axis x|y|z]
"""
import argparse
import bisect
import collections
import math
import os
import sys


def read_ground_truth(path):
    rows = []
    for line in open(path):
        fields = line.split()
        if not fields or line.startswith('#'):
            continue
        t = float(fields[0])
        x, y, z = map(float, fields[1:4])
        qx, qy, qz, qw = map(float, fields[4:8])
        rows.append((t, (x, y, z), (qw, qx, qy, qz)))
    rows.sort()
    return rows


def mean(vectors):
    return [sum(v[i] for v in vectors) / len(vectors) for i in range(3)]


def largest_eigenvector(a):
    """Eigenvector of the largest eigenvalue of a symmetric 4x4 matrix (Jacobi rotations)."""
    a = [row[:] for row in a]
    v = [[float(i == j) for j in range(4)] for i in range(4)]
    for _ in range(100):
        if sum(a[i][j] ** 2 for i in range(4) for j in range(4) if i != j) < 1e-24:
            break
        for p in range(4):
            for q in range(p + 1, 4):
                if abs(a[p][q]) < 1e-30:
                    continue
                theta = (a[q][q] - a[p][p]) / (2 * a[p][q])
                t = (1 if theta >= 0 else -1) / (abs(theta) + math.sqrt(theta * theta + 1))
                c = 1 / math.sqrt(t * t + 1)
                s = t * c
                for k in range(4):
                    akp, akq = a[k][p], a[k][q]
                    a[k][p], a[k][q] = c * akp - s * akq, s * akp + c * akq
                for k in range(4):
                    apk, aqk = a[p][k], a[q][k]
                    a[p][k], a[q][k] = c * apk - s * aqk, s * apk + c * aqk
                for k in range(4):
                    vkp, vkq = v[k][p], v[k][q]
                    v[k][p], v[k][q] = c * vkp - s * vkq, s * vkp + c * vkq
    best = max(range(4), key=lambda i: a[i][i])
    return [v[k][best] for k in range(4)]


def rotation(q):
    w, x, y, z = q
    return [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]


def align(pairs):
    """Similarity (scale, rotation quaternion, centres) taking estimated onto true positions."""
    ce, cg = mean([p[0] for p in pairs]), mean([p[1] for p in pairs])
    e = [[p[0][i] - ce[i] for i in range(3)] for p in pairs]
    g = [[p[1][i] - cg[i] for i in range(3)] for p in pairs]
    s = [[sum(e[k][i] * g[k][j] for k in range(len(pairs))) for j in range(3)] for i in range(3)]
    (sxx, sxy, sxz), (syx, syy, syz), (szx, szy, szz) = s
    n = [[sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
         [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
         [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
         [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz]]
    q = largest_eigenvector(n)
    r = rotation(q)
    re = [[sum(r[i][j] * v[j] for j in range(3)) for i in range(3)] for v in e]
    scale = sum(re[k][i] * g[k][i] for k in range(len(pairs)) for i in range(3)) / \
        sum(v[i] * v[i] for v in e for i in range(3))
    residuals = [[scale * re[k][i] - g[k][i] for i in range(3)] for k in range(len(pairs))]
    return scale, q, residuals


def multiply(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return (w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('run_dir', help='a folder written by `stitch run` (or `stitch map`)')
    parser.add_argument('--gt', help='ground truth, TUM format (default: RUN_DIR/groundtruth.tum)')
    parser.add_argument('--per-keyframe', action='store_true', help="also every keyframe's attitude error")
    parser.add_argument('--axis', choices='xyz', default='y', help='the axis --per-keyframe prints (default: y)')
    args = parser.parse_args()
    merged_path = os.path.join(args.run_dir, 'keyframes_merged.tsv')
    gt_path = args.gt or os.path.join(args.run_dir, 'groundtruth.tum')
    for path in (merged_path, gt_path):
        if not os.path.isfile(path):
            sys.exit('submap-attitude: %s does not exist' % path)
    truth = read_ground_truth(gt_path)
    if not truth:
        sys.exit('submap-attitude: no poses in %s' % gt_path)
    times = [row[0] for row in truth]
    rows = [line.split() for line in open(merged_path) if line.strip() and not line.startswith('#')]
    if not rows:
        sys.exit('submap-attitude: no merged keyframes in %s' % merged_path)
    largest = collections.Counter(r[2] for r in rows).most_common(1)[0][0]
    keyframes = []  # (submap number, position, attitude, true position, true attitude)
    for r in sorted((r for r in rows if r[2] == largest), key=lambda r: int(r[-1])):
        t = int(r[-1]) / 1e9
        i = bisect.bisect_left(times, t)
        nearest = min((j for j in (i - 1, i) if 0 <= j < len(times)), key=lambda j: abs(times[j] - t))
        if abs(times[nearest] - t) > 0.02:
            continue
        qx, qy, qz, qw = map(float, r[4:8])
        keyframes.append(((int(r[1]) >> 32) & 0xffff, tuple(map(float, r[8:11])), (qw, qx, qy, qz),
                          truth[nearest][1], truth[nearest][2]))
    if len(keyframes) < 3:
        sys.exit('submap-attitude: fewer than 3 merged keyframes have a ground-truth pose')
    scale, q, residuals = align([(k[1], k[3]) for k in keyframes])
    rmse = math.sqrt(sum(sum(x * x for x in v) for v in residuals) / len(residuals))
    print('largest merged map: %d keyframes, keyframe ATE %.4f m (one similarity)' % (len(keyframes), rmse))
    by_submap = collections.defaultdict(list)
    for k, residual in zip(keyframes, residuals):
        # the true attitude times the inverse of the aligned estimate
        error = multiply(k[4], tuple(-c if i else c for i, c in enumerate(multiply(q, k[2]))))
        if error[0] < 0:
            error = tuple(-c for c in error)
        by_submap[k[0]].append((k, residual, [2 * math.degrees(c) for c in error[1:]]))
    for number in sorted(by_submap):
        entries = by_submap[number]
        own = align([(e[0][1], e[0][3]) for e in entries])[0] / scale if len(entries) >= 3 else float('nan')
        position = math.sqrt(sum(sum(x * x for x in e[1]) for e in entries) / len(entries))
        attitude = mean([e[2] for e in entries])
        print('submap %d: %d keyframes, scale %.4f of the map\'s, %.4f m in the map, attitude error '
              'x %+.3f y %+.3f z %+.3f deg' % (number, len(entries), own, position, *attitude))
        if args.per_keyframe:
            axis = 'xyz'.index(args.axis)
            print('  ' + ' '.join('%+.2f' % e[2][axis] for e in entries))


if __name__ == '__main__':
    main()
