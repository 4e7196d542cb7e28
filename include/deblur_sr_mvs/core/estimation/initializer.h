// Initialisation of poses and depths from the blurry LR frames alone
// (paper Sec. optInitialization, eq:initializationScene).
#pragma once

#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/frame_types.h"
#include "deblur_sr_mvs/core/geometry/pose_prior.h"
#include "deblur_sr_mvs/core/geometry/se3.h"
#include "deblur_sr_mvs/core/geometry/visibility.h"

namespace deblur_sr_mvs {

struct InitializerOptions {
  int num_threads = 0;  // OpenMP threads; 0 = default

  // --- Feature tracking (Shi-Tomasi corners + pyramidal Lucas-Kanade).
  int max_features = 600;                // corners kept alive per frame
  double feature_quality = 0.005;        // Shi-Tomasi quality, fraction of the best corner
  double min_feature_distance_px = 3.0;  // min spacing of corners (LR px)
  int feature_block_size = 5;            // corner-detector window (LR px)
  int klt_window_radius_px = 5;          // LK window half-size (LR px)
  int klt_levels = 3;                    // LK pyramid levels (motion up to ~2^levels px)
  double klt_max_residual = 0.08;        // mean |intensity difference| ([0,1]) of a kept match
  double max_forward_backward_px = 0.5;  // forward-backward LK disagreement to drop a track
  // When the initialisation fails at the input size for any reason but the
  // lack of parallax, it runs once more on the frames box-downsampled by 2
  // (if that leaves at least 48x48 px), and its depth maps are up-sampled to
  // the input size. Long blur smears the corners along the motion until
  // Lucas-Kanade rejects them; at half size the blur and the motion are half
  // as long in pixels (BENCHMARKS.md "Long blur: the initialiser at half
  // resolution"). InitializeTrajectory, EstimateReadoutTime and
  // EstimateRotationOnlyMotion retry the same way; frames that track at half
  // size and only turn give a NoParallaxError.
  bool half_resolution_retry = true;

  // --- Two-view geometry of the first pair with parallax, PnP of the others.
  double ransac_threshold_px = 1.0;  // essential-matrix RANSAC threshold (LR px)
  double ransac_confidence = 0.999;  // RANSAC confidence (E and PnP)
  int min_inliers = 30;              // features / inliers needed on the two-view pair
  double min_parallax_px = 1.0;      // median pair displacement the rotation leaves, needed (LR px)
  // Median displacement of a pair that NO rotation explains (LR px): the only depth
  // evidence. A pure rotation leaves only tracking noise (0.04 px in
  // InitializerTest.PureRotation...); the bundled scenes' translations leave
  // 0.19 (Aloe) to 0.78 px (Reindeer) on frames 0-1. The two-view start needs
  // a pair that reaches it.
  double min_rotation_free_parallax_px = 0.1;
  double min_triangulation_parallax_px = 2.0;  // rotation-free displacement to add a point (px)
  double pnp_threshold_px = 2.0;               // PnP RANSAC threshold and BA outlier cut (LR px)
  int min_pnp_inliers = 12;                    // PnP inliers needed per later frame
  double ba_loss_px = 1.0;                     // Cauchy scale of the two-view refinement and BA (LR px)
  int ba_max_iterations = 50;                  // Levenberg-Marquardt iterations per BA round
  // After the first bundle adjustment, a track whose squared reprojection
  // errors exceed the chi-square quantile of this one-sided normal quantile
  // (2n - 3 degrees of freedom for n observations, in units of the tracks'
  // noise variance) leaves the adjustment, which runs again without it: a
  // Lucas-Kanade track that slides along an occlusion boundary follows no
  // single point but stays within pnp_threshold_px, where the Cauchy loss
  // weighs it almost fully. With a rolling shutter the test runs after the
  // rows' delays are corrected, and EstimateReadoutTime does not run it (a
  // global-shutter adjustment leaves the delays in the errors of the tracks
  // that carry them). Measured on the benchmark's 24 sequences of
  // seeds 3 and 4 (BENCHMARKS.md "Tracks that follow no point"): joint's
  // ATE 5 % lower on both, its depth rel. error 11 % and 1 % lower, the
  // baseline's likewise; better on arc and forward paths (seed 4's arcs:
  // ATE -28 %), worse on seed 4's hand-held and gain-jitter ones (+10 %,
  // +17 %). 3 and 5 measured alike on seed 3. 0: off.
  double track_consistency_z = 5.0;
  // Prior on each frame-to-frame rotation, as the image shift f * angle (LR
  // px) that costs as much as one 1-px reprojection error: resolves the
  // rotation / translation ambiguity of narrow fields of view.
  double rotation_prior_px = 1.0;
  // A camera that turns as it moves (an arc around the scene, a walker who
  // keeps looking at an object) breaks that prior's assumption. Its turn is
  // the one that keeps a point at distance 1 / kappa on the optical axis: the
  // prior is then measured from that turn, with kappa one more unknown of the
  // bundle adjustment (lateral motion: kappa = 0, the prior above). kappa is
  // kept only when it lowers the reprojection cost by more than the tracking
  // noise explains: a chi-square test of one degree of freedom at the one-
  // sided normal quantile fixation_test_z. The test takes the track errors
  // for independent; they are not (Lucas-Kanade errors persist along a
  // track): on cameras that do not turn (lateral, forward, hand-held paths)
  // the gain reaches ~25-40 sigma^2, the bound of z = 3 is 10.5, z = 4 18.9,
  // z = 6 46.9. So the tracks only screen: a turn they keep must also be
  // confirmed by the dense flow (flow_turn_check below), which drops the
  // tracks' false turns. 4 (6 before 2026-12-06): an arc around a scene of
  // little depth range (Aloe) gains 19.5-31.1 sigma^2, which z = 6 rejected
  // on 5 of 8 seeds (depth rel. error 0.053 against 0.020 with the turn); on
  // 148 sequences of seeds 3-10, z = 4 kept those 5 arcs' turns and 3 false
  // turns on hand-held paths that the flow confirmed (depth +6 to +19 % on
  // those); z = 3 added a fourth, worse one (BENCHMARKS.md "The track
  // screen of the turn test at z = 4"). false: the prior is always towards
  // no rotation.
  bool fixation_prior = true;
  double fixation_test_z = 4.0;
  // Where no flow check follows the track test (flow_turn_check off, a pose
  // prior in the window, the readout search of EstimateReadoutTime), the
  // tracks decide alone, at this quantile: 6, the bound (46.9 sigma^2) that
  // rejects the false turns of ~25-40 sigma^2 without the flow.
  double fixation_test_alone_z = 6.0;
  // Where the tracks reject the turn (the test above), decide it again by
  // the dense images: the depths of stage 4 are computed for both solutions
  // (no turn, and the turn the free kappa fitted), and the turn is kept when
  // it lowers the data cost of eq:initializationScene at the depths'
  // solution by more than dense_test_z standard errors: a paired test of
  // the per-pixel costs, averaged over blocks of dense_test_block_px and
  // over the frames (one sample per block location). A turn traded for a
  // bend of the inverse depths leaves a vertical image displacement of order
  // angle * x * y / f that no depth explains; the tracks' correlated errors
  // hide it, the dense matching sees it at every pixel. Costs a second depth
  // stage where it runs. Not with a rolling shutter or a pose prior (their
  // adjustments decide the turn).
  bool dense_fixation_test = false;
  // The same decision by evidence that no depth can absorb, and without a
  // second depth stage: where the tracks reject the turn, a dense optical
  // flow (OpenCV's DIS) of every pair t -> t+1, t -> t+2 of the LR frames
  // (the gaps flow_test_min_gap..flow_test_max_gap below) is compared with
  // both solutions' epipolar geometry (mid-exposure poses, as the tracks');
  // the distance of each flow end point from its epipolar line
  // does not depend on the depths, so the bas-relief bend that hides the
  // turn from the depth stage cannot hide it here, and a turn's vertical
  // displacement (~ angle * x * y / f) enters linearly, not as a cost's
  // square. The turn is kept when it lowers the mean distance (capped at
  // pnp_threshold_px) by more than dense_test_z standard errors (blocks of
  // dense_test_block_px, one sample per block location, as above).
  // Replaces dense_fixation_test where both are set. Not with a rolling
  // shutter or a pose prior.
  // Only flow that survives the forward-backward check votes: the flow
  // s -> t is computed too, and an end point counts only where
  // |w_f(x) + w_b(x + w_f(x))|^2 < 0.01 (|w_f|^2 + |w_b|^2) + 0.5 px^2
  // (Sundaram, Brox and Keutzer, ECCV 2010: occlusions and flow failures,
  // whose errors are spatially coherent, do not vote). The samples of the
  // flow test are tiles of flow_test_tile_px (clusters of blocks: DIS flow
  // errors are correlated over its patches, so 16 px blocks are not
  // independent), and the bound is Student's t quantile with tiles - 1
  // degrees of freedom at the one-sided level of dense_test_z (few
  // clusters: the cluster-robust test's reference distribution).
  bool flow_fixation_test = false;
  // LR px; > the footprint of a DIS PRESET_MEDIUM patch at its finest scale
  // (12 px at half resolution = 24 LR px): pixels that share no patch.
  int flow_test_tile_px = 32;
  // Frame gaps k of the flow test's pairs t -> t+k: flow_test_min_gap <= k
  // <= flow_test_max_gap (and k < the window's frames; larger values take
  // the window's longest gap). A window with no pair of these gaps keeps no
  // turn. 1, 2: the pairs t -> t+1, t -> t+2. The turn's signal (the
  // vertical displacement ~ angle * x * y / f) grows with the gap, but so
  // does the flow's error on blurred frames: measured, every pair of the
  // window or its long gaps only find no more arcs than gaps 1-2
  // (BENCHMARKS.md, "Long frame gaps in the flow test").
  int flow_test_min_gap = 1;
  int flow_test_max_gap = 2;
  // Where the tracks keep the turn, the flow evidence of the test above must
  // lean towards it: the turn is dropped unless it lowers the flow's
  // epipolar distances by more than flow_turn_check_z (a one-sided normal
  // quantile, taken as Student's t over the tiles like that test's bound).
  // The tracks' errors persist along a track and grow with the window: on
  // 10-frame lateral windows they kept turns of 1.3-1.9 deg that the flow
  // did not support (0.0-0.5 standard errors), while the arcs' turns that
  // they kept had 1.8-4.0 (BENCHMARKS.md, "The tracks' turn checked by the
  // flow"). The flow alone is not trusted to 5 %: on paths that do not turn
  // it reached 2.1 standard errors, which is why a turn that the tracks
  // reject needs dense_test_z. So the check only asks that the flow lean
  // towards the turn by one standard error (the 16 % level); with the track
  // screen at fixation_test_z = 4 the Aloe arcs' turns had 1.54-1.86, the
  // hand-held false turns it kept 1.04, 1.24 and 2.73. One flow per
  // pair of the gaps above, only where the tracks keep a turn; not with a
  // pose prior. With a rolling shutter too: there the tracks' test runs
  // before the rows' delays are corrected, and on 5 of 24 hand-held clips
  // read out over 0.8 of the frame interval it kept turns that the camera
  // did not make (rotation errors 0.9-4.1 deg; the largest, Reindeer seed 3,
  // still passed the tracks' test after the correction), which the flow did
  // not support; it brought them to 0.10-0.40 deg. On rolling-shutter arcs
  // it confirmed every turn the tracks kept (4 of 4). The flow's epipolar
  // lines are those of the frames' mid-exposure poses, for both solutions
  // alike (BENCHMARKS.md, "The flow turn check on rolling-shutter windows").
  bool flow_turn_check = true;
  double flow_turn_check_z = 1.0;
  int dense_test_block_px = 16;  // LR px; > the matching patch and the blur
  // One-sided normal quantile of that test: 3.09 is the 0.1 % level. The
  // blocks make the samples nearly independent, so it is the usual level
  // (the track test's higher bound allows for errors that persist along a
  // track).
  double dense_test_z = 3.09;

  // --- Pose prior (InitializeStructure's T_prior_cam: wheel odometry, VIO,
  // motion capture; docs/file_formats.md#monocular-scale). The bundle-
  // adjusted poses are aligned to the prior's by a robust Sim(3)
  // (AlignToPrior with `pose_prior`: it fixes the gauge and leaves out prior
  // poses that disagree), carried into the prior's frame, and adjusted again
  // with the prior camera centre of every agreeing frame as a soft constraint
  // (Huber loss, quadratic up to 2 sigma) that replaces the pair's unit
  // baseline: the prior's translations then set the scale of the structure,
  // which a narrow field of view leaves weakly tied to the path.
  // Standard deviation of the prior's positions per axis (prior units,
  // metres): a camera centre this far from its prior costs as much as a 1-px
  // reprojection error. 0: the prior is not used in the initialisation.
  double pose_prior_position_sigma = 0.01;
  // The same for the prior's orientations (degrees): an orientation this far
  // from its prior costs as much as a 1-px reprojection error, and the turn
  // rate kappa of the rotation prior is fitted. The orientations decide the
  // turn that the tracks of a narrow field of view leave open (an arc's
  // turn, traded against a bend of the inverse depths); the positions do
  // not. 0: the orientations only enter the alignment.
  double pose_prior_rotation_sigma_deg = 0.1;
  PosePriorOptions pose_prior;  // the alignment's outlier distance, extent needed

  // --- Dense depth (eq:initializationScene): sweep, TV-L1, refinement.
  bool blur_aware = true;    // match Psi_s o B_t against Psi_t o B_s (false: B_t vs B_s)
  int capture_samples = 16;  // M of the scale-1 blur operators of the matching
  // Depth of the virtual cameras by reprojection (paper Sec. 3); false uses
  // D_t(x) itself: 2-3x faster builds, differs only within a blur length of
  // depth edges, where the patch cost is unreliable anyway.
  bool capture_reproject_depth = false;
  int neighbours_per_side = 2;  // frames t-k..t+k matched against frame t
  int num_planes = 64;          // inverse-depth planes of the first (global) sweep
  int refine_planes = 16;       // hypotheses per pixel of each refinement pass
  // Image pyramid levels of the depth passes: the global sweep runs at
  // 1/2^(levels-1) of the input size (coarsest side kept >= 24 px), each finer
  // level refines around the up-sampled result.
  int depth_levels = 2;
  double refine_band = 2.0;         // refinement half-band, in hypothesis steps of the previous pass
  int patch_radius_px = 2;          // matching patch (2r+1)^2 (LR px)
  double cost_truncation = 0.15;    // per-neighbour cost cap (mean |difference|, [0,1] images)
  double depth_range_margin = 0.5;  // widening of the triangulated inverse-depth range (fraction)
  // lambda_d: TV weight per unit gradient of the normalised inverse depth
  // (0..1 over the sweep range) per pixel, in cost units (mean |difference|).
  double depth_tv_weight = 0.05;
  int tv_iterations = 60;         // DTAM alternations per pass
  double theta_start = 0.5;       // initial coupling theta, x (level span)^2
  double theta_end = 1e-4;        // final coupling theta, x (level span)^2
  EdgeWeightOptions edge_weight;  // g_t of eq:regularizingTerm on the input frame

  void Check() const;  // throws InputError naming the bad field
};

// Poses (T_world_cam at each frame's stamp, the shutter close t_c) and LR
// depth maps (on the t_c image grid) in one gauge: world = camera 0 at its
// t_c; monocular scale such that the median of all valid LR depths of the
// window (every frame's depth_lr pixels > 0) is exactly 1
// (docs/file_formats.md#monocular-scale).
struct InitialStructure {
  std::vector<SE3> T_world_cam;
  std::vector<cv::Mat> depth_lr;  // CV_32FC1, input size; NaN where unknown
  std::string summary;            // one line per stage: matches, inliers, residuals
  // The tracks of the points the final bundle adjustment kept (pixels of
  // the input camera; EstimatorOptions::track_pose_weight).
  std::vector<FeatureTrack> tracks;
};

// Thrown when the frames do not allow an initialisation (too few features or
// inliers, no parallax, degenerate geometry); the message says which.
class InitializationError : public std::runtime_error {
 public:
  explicit InitializationError(const std::string& message) : std::runtime_error(message) {}
};

// Thrown only when the frames can be tracked but no pair of them carries
// parallax that a rotation does not explain (a static or purely rotating
// camera): depth and scale are not observable, the orientations are
// (EstimateRotationOnlyMotion). Every other failure is an InitializationError.
class NoParallaxError : public InitializationError {
 public:
  explicit NoParallaxError(const std::string& message) : InitializationError(message) {}
};

// images_lr: the input frames as float in [0, 1] (1 or 3 channels), all of
// camera_lr's size; frames: their stamps and exposures (>= 2 frames). The
// two-view start uses the nearest pair of frames with rotation-free parallax
// (frames 0-1 when they have it), every other frame is registered by PnP.
// Throws InputError on bad inputs, NoParallaxError when no pair has parallax
// (see EstimateRotationOnlyMotion), InitializationError on other failures.
// readout_time > 0: a rolling shutter (docs/file_formats.md#rolling-shutter);
// the tracked points are corrected to a global shutter before the final
// bundle adjustments. T_prior_cam: empty, or per frame its pose in a pose
// prior's frame at the frame's stamp (none where the prior has none); used
// by the bundle adjustment (InitializerOptions::pose_prior_position_sigma).
// The output gauge is the same with or without it. With
// InitializerOptions::half_resolution_retry a failure at the input size is
// followed by a try at half size (the summary then starts with "half
// resolution"); the error thrown when both fail names both reasons.
InitialStructure InitializeStructure(const std::vector<cv::Mat>& images_lr, const PinholeCamera& camera_lr,
                                     const std::vector<FrameRecord>& frames,
                                     const InitializerOptions& options, double readout_time = 0.0,
                                     const std::vector<std::optional<SE3>>& T_prior_cam = {});

// Each frame's pose at its shutter close t_c (its stamp) from its pose at
// mid-exposure, t_c - exposure / 2 (the time the tracks of blurred frames
// observe: they follow the blur centroids), on the path through the
// neighbouring frames' mid-exposure poses: the quadratic through t-1, t and
// t+1, exact on a path of constant acceleration in se(3); the first frame on
// the geodesic through frames 0 and 1, the last on the geodesic through t-1
// and t (eq:interpolatingP), exact at constant velocity. Throws InputError
// with fewer than 2 frames or a pose count that differs from the frames'.
std::vector<SE3> MidExposureToShutterClose(const std::vector<FrameRecord>& frames,
                                           const std::vector<SE3>& T_world_mid);

// Camera poses from the tracks alone: InitializeStructure's sparse part
// (tracks, the two-view start, PnP, the bundle adjustment, the turn checks,
// the rolling-shutter correction) without the dense depth maps, so cheap
// enough for every frame of a long clip (EstimateInWindows ties its windows
// to it). The dense turn test (InitializerOptions::dense_fixation_test) is
// not run. T_world_cam at each frame's stamp (t_c); world = camera 0 at its
// t_c; the scale puts the median depth of the triangulated points, each
// seen from the first frame that tracks it, at 1. Throws as
// InitializeStructure does (NoParallaxError without parallax).
struct InitialTrajectory {
  std::vector<SE3> T_world_cam;
  std::string summary;  // as InitialStructure::summary
};
InitialTrajectory InitializeTrajectory(const std::vector<cv::Mat>& images_lr, const PinholeCamera& camera_lr,
                                       const std::vector<FrameRecord>& frames,
                                       const InitializerOptions& options, double readout_time = 0.0);

// Camera orientations of a window whose motion is (close to) a pure rotation:
// the warps between frames are then homographies K R K^-1 and depth is not
// observable. R_world_cam at each frame's stamp (the shutter close t_c,
// docs/file_formats.md#exposure), world = camera 0 at its t_c.
struct RotationOnlyMotion {
  std::vector<Eigen::Matrix3d> R_world_cam;
  std::string summary;  // one line per stage, like InitialStructure::summary
};

// Same inputs as InitializeStructure. Each frame's rotation relative to the
// earliest frame that shares enough tracks with it is fitted to the rays of
// the matches (RANSAC + Kabsch on unit rays) and chained; these mid-exposure
// orientations (tracks follow blur centroids) are then moved to t_c along
// eq:interpolatingP. Throws InputError on bad inputs and InitializationError
// when the frames cannot be tracked.
RotationOnlyMotion EstimateRotationOnlyMotion(const std::vector<cv::Mat>& images_lr,
                                              const PinholeCamera& camera_lr,
                                              const std::vector<FrameRecord>& frames,
                                              const InitializerOptions& options);

// The rolling shutter's readout time measured from the tracks (`--readout-time
// auto`, the node's `readout_time: auto`; docs/file_formats.md#rolling-shutter).
// A rolling shutter sees row y of frame f y x readout / H later than row 0,
// so a camera that moves puts each tracked point where the camera of that
// instant sees it; a global-shutter bundle adjustment absorbs the part of
// that which constant motion explains (a shear of the scene), not the part
// of a motion that changes. For every candidate fraction of the median frame
// interval the tracks are corrected to a global shutter and bundle-adjusted
// again (as InitializeStructure does with a known readout time), and the
// reprojection cost of one fixed set of observations (the global-shutter
// adjustment's inlier points, each error capped at pnp_threshold_px) is
// compared: the minimum of the grid, refined by a parabola through it and
// its neighbours.
struct ReadoutSearchOptions {
  double max_fraction = 1.0;   // candidates 0 .. max_fraction of the frame interval
  double fraction_step = 0.1;  // their spacing
  // A fraction is reported only when its cost is this much (relative) below
  // the global shutter's; otherwise the readout is 0 (measured = false).
  double min_relative_gain = 0.02;
  void Check() const;  // throws InputError naming the bad field
};

struct ReadoutEstimate {
  bool measured = false;  // false: no candidate beats a global shutter
  double fraction = 0.0;  // of the median frame interval
  double seconds = 0.0;   // fraction x the median frame interval
  // (fraction, RMS reprojection error in LR px over the fixed observations,
  // capped errors included), in increasing fraction; in half-size px where
  // the frames were measured at half resolution (the summary then says so).
  std::vector<std::pair<double, double>> cost;
  // How sharply the cost rises around its minimum: the second difference of
  // the grid there over the minimum (at fraction 0 twice the first step's
  // rise). A motion that barely changes leaves the curve flat (about 0.006
  // on the benchmark's hand-held sequences against 0.06 where it changes more):
  // what a stream weighs its windows' measurements by.
  double sharpness = 0.0;
  double elapsed_seconds = 0.0;
  std::string summary;  // one line: the estimate, its cost against a global shutter, the time
};

// Same inputs as InitializeStructure (the frames' exposures are used as they
// are). Throws InputError on bad inputs and InitializationError when the
// frames cannot be initialised (NoParallaxError without parallax: a
// rotation's readout is not measured here).
ReadoutEstimate EstimateReadoutTime(const std::vector<cv::Mat>& images_lr, const PinholeCamera& camera_lr,
                                    const std::vector<FrameRecord>& frames, const InitializerOptions& options,
                                    const ReadoutSearchOptions& search);

}  // namespace deblur_sr_mvs
