#!/usr/bin/env python3
"""Breaks each stage of the tracker, the mapper and the merger's acceptance checks once and checks that its unit test fails.

For each deliberate mistake below: edit the source, rebuild the stage's test program, run the
stage's tests, restore the source (always). Prints CAUGHT (a test failed, as it must) or MISSED
(no test noticed: a gap in the tests) per mistake; exits 1 if any was missed.

usage: tools/check-stage-tests.py [--build DIR] [WORD ...]   (WORDs pick mistakes by name)
"""
import argparse
import os
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# (name, file, text, replacement, test program, gtest filter); a list of (text, replacement)
# pairs in place of `text` makes several edits (the replacement is then None).
MISTAKES = [
 ("initialization: wrong correspondences","src/stitch/tracking/initializer.cc","p2.push_back(frame.undistorted[matches[i]]);","p2.push_back(frame.undistorted[(matches[i] + 1) % frame.size()]);","tracking_test","Initializer.*"),
 ("initialization: H/F choice inverted","src/stitch/estimators/two_view.cc","const bool use_h = score_h / (score_h + score_f) > options.homography_ratio;","const bool use_h = score_h / (score_h + score_f) <= options.homography_ratio;","tracking_test","Initializer.*"),
 ("initialization: static camera (parallax and triangulation checks)","src/stitch/estimators/two_view.cc",[("if (c.parallax_deg >= options.min_parallax_deg) valid.push_back(c);","valid.push_back(c);"),("if (best.num_good < options.min_good_fraction * model_inliers) {","if (false) {"),("c.good[i] = cos_parallax < 0.99998;","c.good[i] = true;")],None,"tracking_test","Initializer.AStill*"),
 ("motion model: pose not optimized","src/stitch/tracking/frame_placer.cc","  const int inliers = OptimizeFramePose(map, frame, true);\n  return inliers >= 10 ? inliers : 0;","  return matches;","tracking_test","FramePlacer.MotionModel*"),
 ("reference keyframe: pose not optimized","src/stitch/tracking/frame_placer.cc","  return OptimizeFramePose(map, frame, true) >= 10;\n}\n\nbool FramePlacer::TrackLocalMap","  return true;\n}\n\nbool FramePlacer::TrackLocalMap","tracking_test","FramePlacer.Reference*"),
 ("homography: predictions ignored","src/stitch/tracking/frame_placer.cc","if (p.z() > 1e-9) predicted[i] = p.hnormalized();","if (p.z() > 1e-9) predicted[i] = last.undistorted[i];","tracking_test","FramePlacer.Homography*"),
 ("local map: no projection search","src/stitch/tracking/frame_placer.cc","  SearchByProjection(frame, in_view, map, 1.0);\n  return OptimizeFramePose","  return OptimizeFramePose","tracking_test","FramePlacer.LocalMap*"),
 ("placer order: homography before motion model","src/stitch/tracking/frame_placer.cc","  int motion_inliers = 0;\n  if (velocity && last && gap >= 1) {","  int motion_inliers = 0;\n  if (last) attempt(\"homography\", [&] { return TrackWithHomography(map, frame, *last); });\n  if (velocity && last && gap >= 1) {","tracking_test","FramePlacer.PlacesInTheStatedOrder"),
 ("keyframe decision: ratio inverted","src/stitch/tracking/keyframe_decision.cc","input.tracked_points < options.keyframe_ratio * input.reference_points","input.tracked_points > options.keyframe_ratio * input.reference_points","tracking_test","KeyframeDecision.*"),
 ("relocalization: candidates filtered away","src/stitch/tracking/relocalizer.cc","return c.common_words < 0.8 * most_common;","return c.common_words <= most_common;","tracking_test","Relocalizer.*"),
 ("relocalization: no local-map confirmation","src/stitch/tracking/relocalizer.cc","  return placer_->TrackLocalMap(map, frame, options_.relocalization_min_inliers, reference);","  placer_->TrackLocalMap(map, frame, options_.relocalization_min_inliers, reference);\n  return true;","tracking_test","Relocalizer.*"),
 ("triangulation: rays swapped","src/stitch/mapping/new_points.cc","TriangulateDlt(kf1->cam_from_world, n1, kf2->cam_from_world, n2)","TriangulateDlt(kf1->cam_from_world, n2, kf2->cam_from_world, n1)","mapping_test","Triangulation.*"),
 ("fusion: off","src/stitch/mapping/new_points.cc","  int fused = 0;\n","  int fused = 0;\n  if (fused == 0) return 0;\n","mapping_test","Fusion.*"),
 ("point culling: age limit","src/stitch/mapping/culling.cc","(age >= 2 && static_cast<int>(point->observations.size()) <= min_observations)","(age >= 20 && static_cast<int>(point->observations.size()) <= min_observations)","mapping_test","PointCulling.*"),
 ("local BA: window fixed","src/stitch/estimators/bundle_adjustment.cc","  return BundleAdjust(map, window, {}, k, options, interrupted);","  return BundleAdjust(map, {}, window, k, options, interrupted);","mapping_test","LocalBundleAdjustment.*"),
 ("local BA: window not capped","src/stitch/estimators/bundle_adjustment.cc","if (options.max_free_keyframes > 0 && static_cast<int>(window.size()) >= options.max_free_keyframes) break;","","estimators_test","BundleAdjustment.TheLocalWindow*"),
 ("local BA: interruption ignored","src/stitch/estimators/bundle_adjustment.cc","    if (!interrupted_ || !interrupted_()) return ceres::SOLVER_CONTINUE;","    return ceres::SOLVER_CONTINUE;","estimators_test","BundleAdjustment.AnInterruption*"),
 ("mapper: a waiting keyframe ignored","src/stitch/mapping/local_mapping.cc","  if (next_waiting && next_waiting()) {","  if (false) {","mapping_test","LocalMapping.*"),
 ("mapper: new points not sent first","src/stitch/mapping/local_mapping.cc","  if (hooks.new_points_made && !created.empty())","  if (false)","mapping_test","LocalMapping.*"),
 ("keyframe decision: keyframes in flight ignored","src/stitch/tracking/tracking.cc","KeyframesInFlight() < options_.keyframes_in_flight","true","tracking_test","KeyframeDecision.*"),
 ("keyframe culling: redundancy test","src/stitch/mapping/culling.cc","if (points > 0 && redundant > redundancy * points) {","if (points > 0 && redundant > points) {","mapping_test","KeyframeCulling.*"),
 ("keyframe culling: keeps nothing","src/stitch/mapping/culling.cc","if (candidate == keep || candidate == keyframe) continue;","if (candidate == keyframe) continue;","mapping_test","KeyframeCulling.*"),
]

MISTAKES += [
 ("merger acceptance: points on a line accepted","src/stitch/merging/submap_graph.cc","if (g.line_ratio < options.min_line_ratio) {","if (false) {","acceptance_test","Acceptance.PointsOnALine*"),
 ("merger acceptance: parallel rays accepted","src/stitch/merging/submap_graph.cc","if (spread < options.min_bearing_spread) {","if (false) {","acceptance_test","Acceptance.PointsSeenAlongParallel*"),
 ("merger acceptance: an edge of one connected frame","src/stitch/merging/submap_graph.cc","if (e.connected_frames < options.min_connected_frames) {","if (false) {","acceptance_test","Acceptance.AnEdgeOfOne*"),
 ("merger acceptance: a split vote","src/stitch/merging/submap_graph.cc","} else if (e.agreement < options.min_agreement) {","} else if (false) {","acceptance_test","Acceptance.AnEdgeWhose*"),
 ("merger acceptance: a cycle that does not close","src/stitch/merging/submap_graph.cc","if (SimilaritiesAgree(placed, e.b_from_a)) continue;","continue;","acceptance_test","Acceptance.AnEdgeOnACycle*"),
 ("merger acceptance: stale connections vote","src/stitch/merging/submap_graph.cc","return !any_fresh || !m.stale;","return true;","acceptance_test","Acceptance.StaleConnected*"),
 ("merger acceptance: never verified again","src/stitch/merging/merger.cc","if (c.revision_a == a.newest_revision && c.revision_b == b.newest_revision) {","if (true) {","acceptance_test","Acceptance.ConnectionsVerified*"),
]


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", default=os.path.join(ROOT, "build"), help="a configured build folder")
    parser.add_argument("words", nargs="*", help="only the mistakes whose name holds one of these")
    args = parser.parse_args()
    if not os.path.exists(os.path.join(args.build, "CMakeCache.txt")):
        sys.exit(f"{args.build}: not a configured build folder (cmake -S . -B build first)")
    missed = 0
    for name, path, text, replacement, program, test_filter in MISTAKES:
        if args.words and not any(word in name for word in args.words):
            continue
        source = os.path.join(ROOT, path)
        with open(source) as f:
            original = f.read()
        edits = text if isinstance(text, list) else [(text, replacement)]
        if any(old not in original for old, _ in edits):
            print(f"STALE   {name}: the text to break is no longer in {path}; update this script")
            missed += 1
            continue
        backup = tempfile.NamedTemporaryFile(delete=False)
        backup.close()
        shutil.copy(source, backup.name)
        try:
            broken = original
            for old, new in edits:
                broken = broken.replace(old, new, 1)
            with open(source, "w") as f:
                f.write(broken)
            build = subprocess.run(["cmake", "--build", args.build, "--target", program], capture_output=True, text=True)
            if build.returncode != 0:
                print(f"BROKEN  {name}: does not build\n{build.stdout[-800:]}")
                missed += 1
                continue
            run = subprocess.run([os.path.join(args.build, "bin", "tests", program), "--gtest_filter=" + test_filter],
                                 capture_output=True, text=True, timeout=600)
            failed = sorted({line.split("]", 1)[1].split()[0] for line in run.stdout.splitlines()
                             if line.startswith("[  FAILED  ]") and "listed below" not in line and "." in line})
            if run.returncode != 0:
                print(f"CAUGHT  {name}: {', '.join(failed) or 'the test program failed'}")
            else:
                print(f"MISSED  {name}: {test_filter} still passes")
                missed += 1
        finally:
            shutil.copy(backup.name, source)
            os.unlink(backup.name)
    # Leave the test programs built from the restored sources.
    subprocess.run(["cmake", "--build", args.build, "--target", "tracking_test", "mapping_test", "estimators_test"],
                   capture_output=True)
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
