// estimate_sequence: sequence folder -> result folder (docs/file_formats.md, docs/tools.md).
// Runs the joint estimator (or the baseline) and writes the HR latent images,
// HR depth maps, poses and report.json. A progress bar is drawn when stderr
// is a terminal. Bad input: one line on stderr, exit code 2.
// With --pose-prior the outputs are carried into the prior's frame and units
// (docs/file_formats.md#monocular-scale).
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <limits>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/common/runtime.h"
#include "deblur_sr_mvs/core/common/weighted_median.h"
#include "deblur_sr_mvs/core/estimation/depth_confidence.h"
#include "deblur_sr_mvs/core/estimation/estimator.h"
#include "deblur_sr_mvs/core/estimation/exposure_estimation.h"
#include "deblur_sr_mvs/core/estimation/initializer.h"
#include "deblur_sr_mvs/core/estimation/stream.h"
#include "deblur_sr_mvs/core/estimation/windowed_run.h"
#include "deblur_sr_mvs/core/geometry/pose_prior.h"
#include "deblur_sr_mvs/core/imaging/image_ops.h"
#include "deblur_sr_mvs/core/io/result_io.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"
#include "estimate_report.h"
#include "tool_main.h"

namespace dsm = deblur_sr_mvs;

namespace {

constexpr char kDescription[] =
    "estimate_sequence: sequence folder -> result folder (HR latent images, HR depth maps,\n"
    "poses, report.json). Defaults are the paper's: joint, scale 2, 3 iterations, M 50,\n"
    "lambda_s 30, lambda_d 0.1 (see README), lambda_i 0.45, neighbours 1; pose-neighbours 2,\n"
    "structure-matching both (see README); threads 0 = all cores.";

// --window-size auto: the most frames (at most the stream's 64) whose
// estimated memory, kBytesPerHrValue per HR pixel and channel and frame,
// stays within kWindowMemoryBytes, and at least kMinAutoWindow. Measured
// peaks: 145-149 bytes per HR value at 640x480 HR in colour (10 frames,
// 1.25-1.28 GiB), 100-118 at 320x240 (24 and 60 frames; BENCHMARKS.md
// "Window size by memory"). So a colour sequence of up to 58 frames at
// 640x480 HR (64 at 320x240) is one window, as before; a longer one runs in
// windows.
constexpr double kBytesPerHrValue = 160.0;
constexpr double kWindowMemoryBytes = 8.0 * 1024 * 1024 * 1024;
constexpr int kMinAutoWindow = 10;
constexpr int kMaxWindow = 64;  // StreamOptions::Check's bound
int AutoWindowSize(const dsm::EstimatorInput& input, int scale) {
  const double values = static_cast<double>(input.camera.width) * input.camera.height * scale * scale *
                        (input.images.empty() ? 1 : input.images.front().channels());
  const double frames = std::floor(kWindowMemoryBytes / (kBytesPerHrValue * values));
  return static_cast<int>(
      std::clamp(frames, static_cast<double>(kMinAutoWindow), static_cast<double>(kMaxWindow)));
}

struct Flags {
  std::string input, output;
  std::string pose_prior;  // TUM file of T_prior_cam, empty = none
  std::string mode = "joint";
  std::string structure_matching = "both";
  std::string exposure;              // "auto": estimated from the blur; empty: frames.csv's
  std::string readout_time;          // "auto": measured from the tracks; empty: sensor.yaml's
  std::string noise_sigma = "auto";  // "auto" or 8-bit gray levels
  bool fixed_poses = false;
  bool fixed_samples = false;
  bool quiet = false;
  int output_scale = 1;  // bicubic up-sampling of the outputs ("w/o SR + Bic.")
  // Longer sequences are estimated in windows of at most this many frames,
  // as the node streams them (EstimateInWindows); 0: one window of every
  // frame; "auto": AutoWindowSize.
  std::string window_size = "auto";
  dsm::WindowedRunOptions windowing;
  // Depth whose confidence is below this is written as NaN (0: all depth).
  double depth_confidence_threshold = dsm::DepthConfidenceOptions().threshold;
};

double PeakMemoryMiB() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0;  // Linux: KiB
}

// --noise-sigma: "auto" (negative: estimated) or gray levels of 8-bit frames.
double ParseNoiseSigma(const std::string& text) {
  if (text == "auto") return -1.0;
  char* end = nullptr;
  const double gray_levels = std::strtod(text.c_str(), &end);
  if (end == text.c_str() || *end != '\0' || !(gray_levels >= 0.0 && gray_levels <= 255.0))
    throw dsm::InputError("--noise-sigma: expected auto or gray levels in [0, 255], got '" + text + "'");
  return gray_levels / 255.0;
}

// --window-size, --window-overlap, --tie-windows.
void AddWindowOptions(dsm::ToolCommandLine* cli, Flags* flags) {
  cli->add_option(
      "--window-size", flags->window_size,
      "a sequence of more frames is estimated in overlapping windows of at most this many (3-64), "
      "as the node streams it: memory grows with the window, not the sequence; 0: one window of "
      "every frame; auto (default): the most frames, up to 64, that fit in about 8 GiB (at least "
      "10)");
  cli->add_option("--window-overlap", flags->windowing.window_overlap,
                  "with --window-size: frames shared by consecutive windows, 2 .. window size - 1 "
                  "(default 2)")
      ->check(dsm::FlagInt(2, 63));
  cli->add_flag("--tie-windows,!--no-tie-windows", flags->windowing.tie_to_sequence_trajectory,
                "with more than one window: the whole sequence's trajectory from its tracks (one bundle "
                "adjustment) holds the windows' poses together as a pose prior, unless --pose-prior gives "
                "one (default on)");
}

// WindowedRunOptions::Check, naming the flags.
void CheckWindowing(const dsm::WindowedRunOptions& windowing) {
  try {
    windowing.Check();
  } catch (const dsm::InputError& error) {
    throw dsm::InputError(std::string("--window-size / --window-overlap: ") + error.what());
  }
}

// --window-size: -1 for "auto", else 0 or 3-64 (InputError otherwise).
int ParseWindowSize(const std::string& text) {
  if (text == "auto") return -1;
  char* end = nullptr;
  const long size = std::strtol(text.c_str(), &end, 10);
  if (end == text.c_str() || *end != '\0' || size < 0 || size > kMaxWindow) {
    throw dsm::InputError("--window-size: expected auto or a whole number of frames in [0, 64], got '" +
                          text + "'");
  }
  return static_cast<int>(size);
}

// The windows of this input: --window-size auto resolved (AutoWindowSize).
dsm::WindowedRunOptions Windowing(const Flags& flags, const dsm::EstimatorInput& input, int scale) {
  dsm::WindowedRunOptions windowing = flags.windowing;
  if (windowing.window_size < 0) windowing.window_size = AutoWindowSize(input, scale);
  CheckWindowing(windowing);
  return windowing;
}

// --pose-prior and the weights of its poses in the initialisation and the
// iterations.
void AddPosePriorOptions(dsm::ToolCommandLine* command_line, Flags* flags, dsm::EstimatorOptions* options) {
  dsm::ToolCommandLine& cli = *command_line;
  cli.add_option("--pose-prior", flags->pose_prior,
                 "TUM trajectory (T_world_camera, metres) of the same camera: the initialisation's bundle "
                 "adjustment follows its poses (--pose-prior-sigma, --pose-prior-rotation-sigma), output poses "
                 "are in its frame, "
                 "depth in its units")
      ->check(CLI::ExistingFile);
  cli.add_option("--pose-prior-sigma", options->initializer.pose_prior_position_sigma,
                 "with --pose-prior: standard deviation of its positions per axis (its units, metres) in "
                 "the bundle adjustment; 0: the prior only aligns the output (default 0.01)")
      ->check(dsm::FlagNumber(0.0));
  cli.add_option("--pose-prior-rotation-sigma", options->initializer.pose_prior_rotation_sigma_deg,
                 "with --pose-prior: standard deviation of its orientations (degrees) in the bundle "
                 "adjustment; 0: its orientations only align the output (default 0.1)")
      ->check(dsm::FlagNumber(0.0));
  cli.add_option(
         "--fixation-test-z", options->initializer.fixation_test_z,
         "initialisation: one-sided normal quantile of the test that keeps a turning camera's "
         "rotation prior (a turn towards a fixation point) against the prior of no turn; --flow-turn-check "
         "then confirms it (default 4)")
      ->check(dsm::FlagNumber(1e-12));
  cli.add_option("--fixation-test-alone-z", options->initializer.fixation_test_alone_z,
                 "initialisation: that quantile where no flow turn check follows (--no-flow-turn-check, "
                 "--pose-prior, the readout search of --readout-time auto; default 6)")
      ->check(dsm::FlagNumber(1e-12));
  cli.add_option(
         "--track-consistency-z", options->initializer.track_consistency_z,
         "initialisation: one-sided normal quantile of the chi-square test that leaves out the tracks "
         "the first bundle adjustment does not explain to the tracking noise (0: off; default 5)")
      ->check(dsm::FlagNumber(0.0));
  cli.add_flag("--dense-fixation-test,!--no-dense-fixation-test", options->initializer.dense_fixation_test,
               "initialisation: where the tracks reject a turning camera, decide the turn again by the "
               "dense depths' data cost of both solutions (a second depth stage; default off)");
  cli.add_flag("--flow-fixation-test,!--no-flow-fixation-test", options->initializer.flow_fixation_test,
               "initialisation: where the tracks reject a turning camera, decide the turn again by the "
               "epipolar distances of a dense optical flow under both solutions (replaces "
               "--dense-fixation-test; default off)");
  cli.add_flag("--flow-turn-check,!--no-flow-turn-check", options->initializer.flow_turn_check,
               "initialisation: where the track test keeps a turning camera, the dense flow's epipolar "
               "distances (as --flow-fixation-test) must confirm the turn, or it is dropped (default: on)");
  cli.add_option("--flow-turn-check-z", options->initializer.flow_turn_check_z,
                 "with --flow-turn-check: one-sided normal quantile of that confirmation (Student's t over the "
                 "tiles; 1: the flow leans towards the turn by one standard error)");
  cli.add_option("--flow-test-tile-px", options->initializer.flow_test_tile_px,
                 "with --flow-fixation-test: LR px of the tiles that are its samples (clusters of the "
                 "flow's correlated errors; default 32)")
      ->check(dsm::FlagNumber(1.0));
  cli.add_option("--flow-test-min-gap", options->initializer.flow_test_min_gap,
                 "with --flow-fixation-test: shortest frame gap k of its flow pairs t -> t+k (default 1)")
      ->check(dsm::FlagInt(1));
  cli.add_option("--flow-test-max-gap", options->initializer.flow_test_max_gap,
                 "with --flow-fixation-test: longest frame gap k of its flow pairs t -> t+k; larger than "
                 "the window: its longest (default 2)")
      ->check(dsm::FlagInt(1));
  cli.add_option("--dense-fixation-test-z", options->initializer.dense_test_z,
                 "with --dense-fixation-test or --flow-fixation-test: standard errors by which the turn must "
                 "lower the dense data cost or the flow's epipolar distances (default 3.09, the 0.1 % level)")
      ->check(dsm::FlagNumber(1e-12));
  cli.add_flag("--pose-prior-iterations,!--no-pose-prior-iterations", options->pose_prior_in_iterations,
               "with --pose-prior: the joint iterations' pose steps keep its centres and orientations as "
               "terms with the same sigmas (default on)");
  cli.add_option("--pose-prior-weight", options->pose_prior_weight,
                 "with --pose-prior-iterations: weight of the prior's terms against the photometric ones "
                 "(default 1e4)")
      ->check(dsm::FlagNumber(1e-12));
  cli.add_option("--track-pose-weight", options->track_pose_weight,
                 "joint: weight of the initialiser's feature tracks in the pose steps, against the "
                 "photometric terms; 0 = off (default 1000)")
      ->check(dsm::FlagNumber(0.0));
  cli.add_option("--track-pose-gate", options->track_pose_gate_start,
                 "with --track-pose-weight: the tracks act where the poses raise their cost more than this "
                 "fraction above its least value (default 0.2)")
      ->check(dsm::FlagNumber(0.0));
}

// --blur-pose-evidence and its sampling and weight.
void AddBlurPoseOptions(dsm::ToolCommandLine* command_line, dsm::EstimatorOptions* options) {
  dsm::ToolCommandLine& cli = *command_line;
  cli.add_flag("--blur-pose-evidence,!--no-blur-pose-evidence", options->blur_pose_evidence,
               "joint: the pose update also fits the blur of each frame (the self-consistency term "
               "linearised in the poses of its blur path; default off)");
  cli.add_option("--blur-pose-weight", options->structure.blur_pose_weight,
                 "with --blur-pose-evidence: its weight relative to lambda_s (self term) or to 1 (pairs)")
      ->check(dsm::FlagNumber());
  cli.add_option("--blur-pose-samples", options->structure.blur_pose_samples,
                 "with --blur-pose-evidence: virtual cameras per frame for its Jacobian")
      ->check(dsm::FlagInt());
  cli.add_flag("--blur-pose-from-pairs", options->structure.blur_pose_from_pairs,
               "with --blur-pose-evidence: the sharp image is the neighbours' latent images warped into t "
               "(blurred matching pairs), not I_t");
  cli.add_option("--blur-pose-stride", options->structure.blur_pose_stride,
                 "with --blur-pose-evidence: every N-th LR pixel and row")
      ->check(dsm::FlagInt());
}

// --depth-edge-radius and where the refinement applies.
void AddDepthEdgeOptions(dsm::ToolCommandLine* command_line, dsm::EstimatorOptions* options) {
  dsm::ToolCommandLine& cli = *command_line;
  cli.add_option("--depth-edge-radius", options->depth_edges.radius_px,
                 "edge-aware weighted median of the depth guided by the latent image: window radius "
                 "(HR px; 0: off; default 8)")
      ->check(dsm::FlagInt());
  cli.add_option("--depth-edge-sigma", options->depth_edges.sigma,
                 "with --depth-edge-radius: colour distance scale of the guide weights (intensity in [0, 1])")
      ->check(dsm::FlagNumber());
  cli.add_flag("--depth-edge-before-structure,!--no-depth-edge-before-structure",
               options->depth_edges.before_structure_update,
               "with --depth-edge-radius: refine every depth before each structure update (default off)");
  cli.add_flag("--depth-edge-on-output,!--no-depth-edge-on-output", options->depth_edges.on_output,
               "with --depth-edge-radius: refine the output depth (default on)");
}

// --fusion-*: the temporal fusion of the output images.
void AddFusionOptions(dsm::ToolCommandLine* command_line, dsm::EstimatorOptions* options) {
  dsm::ToolCommandLine& cli = *command_line;
  cli.add_option("--fusion-radius", options->fusion.radius,
                 "joint: fuse each restored image with those of the frames up to N away, warped by the final "
                 "depth and poses (0: off; default 2)")
      ->check(dsm::FlagInt());
  cli.add_option("--fusion-scale", options->fusion.distance_scale,
                 "with --fusion-radius: the patch weight's distance scale h (intensity "
                 "in [0, 1]; default 0.051, 13 gray levels)")
      ->check(dsm::FlagNumber());
  cli.add_option("--fusion-patch", options->fusion.patch_px,
                 "with --fusion-radius: side of the patch of the weight (odd, px; default 5)")
      ->check(dsm::FlagInt());
  cli.add_flag("--fusion-between-updates,!--no-fusion-between-updates", options->fusion.between_updates,
               "with --fusion-radius: also fuse the restored images before each structure update (default off)");
}

// --depth-consistency-*: the consistency between neighbouring depth maps.
void AddDepthConsistencyOptions(dsm::ToolCommandLine* command_line, dsm::EstimatorOptions* options) {
  dsm::ToolCommandLine& cli = *command_line;
  dsm::DepthConsistencyOptions& consistency = options->depth_consistency;
  // The tool's default; the library's is off (DepthConsistencyOptions::radius 0),
  // as for the output re-sweep: with a pose prior the stage lowers the
  // scale-aligned depth error but not the error in metres.
  consistency.radius = 2;
  cli.add_option("--depth-consistency-radius", consistency.radius,
                 "replace each output depth by the mean (in inverse depth) of it and the depths of the frames "
                 "up to N away that agree with it (0: off; default 2)")
      ->check(dsm::FlagInt());
  cli.add_option("--depth-consistency-tolerance", consistency.tolerance,
                 "with --depth-consistency-radius: relative inverse-depth difference up to which a neighbour "
                 "agrees (default 0.1)")
      ->check(dsm::FlagNumber());
  cli.add_flag_callback(
      "--depth-consistency-median",
      [&consistency] { consistency.combination = dsm::DepthConsistencyOptions::Combination::kMedian; },
      "with --depth-consistency-radius: the median of the agreeing depths instead of their mean");
}

// --multi-frame-*: the multi-frame data pass after the last image update.
void AddMultiFrameDataOptions(dsm::ToolCommandLine* command_line, dsm::EstimatorOptions* options) {
  dsm::ToolCommandLine& cli = *command_line;
  dsm::MultiFrameDataOptions& pass = options->multi_frame_data;
  cli.add_option("--multi-frame-weight", pass.relative_weight,
                 "joint: re-solve each restored image with its agreeing neighbours' matching terms at this "
                 "fraction of lambda_s (0: off; default 1)")
      ->check(dsm::FlagNumber());
  cli.add_option("--multi-frame-radius", pass.radius,
                 "with --multi-frame-weight: the neighbours taken, frames up to N away (default 1)")
      ->check(dsm::FlagInt());
  cli.add_option("--multi-frame-agreement", pass.agreement_scale,
                 "with --multi-frame-weight: a neighbour pixel agrees where its patch RMS residual is at most "
                 "this times the expected one (default 2)")
      ->check(dsm::FlagNumber());
  cli.add_flag("--multi-frame-skip-first,!--no-multi-frame-skip-first", pass.skip_first_frame,
               "with --multi-frame-weight: leave frame 0 (its blur path extrapolated) out of the pass (default on)");
  cli.add_option("--multi-frame-irls", pass.irls_iterations,
                 "with --multi-frame-weight: the pass's reweightings (default 2)")
      ->check(dsm::FlagInt());
}

// --denoised-anchor: the plug-and-play anchor of the last image pass.
void AddDenoisedAnchorOptions(dsm::ToolCommandLine* command_line, dsm::EstimatorOptions* options) {
  dsm::ToolCommandLine& cli = *command_line;
  dsm::DenoisedAnchorOptions& anchor = options->denoised_anchor;
  cli.add_flag("--denoised-anchor,!--no-denoised-anchor", anchor.enabled,
               "joint, noisy frames: pull each restored image in the last pass towards its non-local-means "
               "denoised copy (default off; no effect where the noise estimate is below its floor)");
  cli.add_flag("--input-denoising,!--no-input-denoising", options->input_denoising.enabled,
               "filter the frames with 3-frame non-local means at h = the noise estimate above its floor "
               "before estimating (no effect on noise-free frames)");
  cli.add_option("--input-denoising-h-scale", options->input_denoising.h_scale,
                 "with --input-denoising: h over the input noise (default 1)")
      ->check(dsm::FlagNumber());
  cli.add_option("--anchor-weight-scale", anchor.weight_scale,
                 "with --denoised-anchor: scale of the proximity weight (default 1)")
      ->check(dsm::FlagNumber());
  cli.add_option("--anchor-h-scale", anchor.h_scale,
                 "with --denoised-anchor: NLM h over the predicted amplified noise (default 1)")
      ->check(dsm::FlagNumber());
  cli.add_option_function<std::string>(
         "--anchor-denoiser",
         [&anchor](const std::string& name) {
           anchor.denoiser =
               name == "nlm" ? dsm::AnchorDenoiser::kNonLocalMeans : dsm::AnchorDenoiser::kTemporalFusion;
         },
         "with --denoised-anchor: fusion (the temporal fusion of the window's restored images; default) or "
         "nlm (single-image non-local means)")
      ->check(CLI::IsMember({"fusion", "nlm"}));
  cli.add_option("--anchor-amplification", anchor.amplification,
                 "with --denoised-anchor: the restored image's noise over the input noise (default 3)")
      ->check(dsm::FlagNumber());
}

// --depth-sweep and its sweep's settings.
void AddDepthSweepOptions(dsm::ToolCommandLine* command_line, dsm::EstimatorOptions* options) {
  dsm::ToolCommandLine& cli = *command_line;
  // The tool's default; the library's is off (DepthSweepOptions::on_output).
  options->depth_sweep.on_output = true;
  cli.add_flag("--depth-sweep,!--no-depth-sweep", options->depth_sweep.on_output,
               "joint mode: re-sweep the output depth over the restored images (plane sweep, guided-filter "
               "cost aggregation) where it clearly disagrees with the solver's (default on)");
  cli.add_option("--depth-sweep-planes", options->depth_sweep.num_planes,
                 "with --depth-sweep: inverse-depth planes over each frame's range")
      ->check(dsm::FlagInt());
  cli.add_option("--depth-sweep-radius", options->depth_sweep.aggregation_radius_px,
                 "with --depth-sweep: guided-filter radius of the cost aggregation (HR px)")
      ->check(dsm::FlagInt());
  cli.add_option("--depth-sweep-eps", options->depth_sweep.aggregation_eps,
                 "with --depth-sweep: guided-filter regularisation (intensity^2)")
      ->check(dsm::FlagNumber());
  cli.add_option("--depth-sweep-truncation", options->depth_sweep.cost_truncation,
                 "with --depth-sweep: per-neighbour cost cap (mean |difference|)")
      ->check(dsm::FlagNumber());
  cli.add_option("--depth-sweep-keep-steps", options->depth_sweep.keep_steps,
                 "with --depth-sweep: keep the solver's depth within this many plane steps of the sweep's")
      ->check(dsm::FlagNumber());
  cli.add_option("--depth-sweep-min-gain", options->depth_sweep.min_cost_gain,
                 "with --depth-sweep: keep the solver's depth unless the sweep's cost is lower by this fraction")
      ->check(dsm::FlagNumber());
  cli.add_option("--depth-sweep-min-guide-std", options->depth_sweep.min_guide_std,
                 "with --depth-sweep: keep the solver's depth where the restored image's standard deviation over the "
                 "aggregation window is below this (intensity in [0, 1])")
      ->check(dsm::FlagNumber());
  cli.add_option("--depth-sweep-downsample", options->depth_sweep.downsample,
                 "with --depth-sweep: sweep on the images downsampled by this factor (1: HR)")
      ->check(dsm::FlagInt());
  cli.add_option("--depth-sweep-before-last", options->depth_sweep.before_last_structure_updates,
                 "joint mode: also re-sweep the solver's depth before the last N structure updates (0: never)")
      ->check(dsm::FlagInt());
  cli.add_option("--depth-sweep-neighbours", options->depth_sweep.neighbour_radius,
                 "with --depth-sweep: match each frame against the frames within this distance")
      ->check(dsm::FlagInt());
}

// --joint-depth-pose-step, its solver and its coarse-to-fine levels.
void AddJointStepOptions(dsm::ToolCommandLine* command_line, dsm::EstimatorOptions* options) {
  dsm::ToolCommandLine& cli = *command_line;
  cli.add_flag("--joint-depth-pose-step,!--no-joint-depth-pose-step",
               options->structure.joint_depth_pose_step,
               "the structure update moves all depths and the free poses in one Gauss-Newton step "
               "(default on; off: per-frame depth updates)");
  cli.add_option(
         "--joint-coarse-levels", options->structure.joint_coarse_levels,
         "with the joint step: coarse-to-fine, this many levels at 1/2, 1/4, ... first (0: off; default 1)")
      ->check(dsm::FlagInt());
  cli.add_option("--joint-pose-damping", options->structure.joint_pose_damping,
                 "with --joint-depth-pose-step: Levenberg-Marquardt damping of the poses, relative to "
                 "their diagonal")
      ->check(dsm::FlagNumber());
  cli.add_option("--joint-cg-iterations", options->structure.joint_cg_iterations,
                 "with --joint-depth-pose-step: CG steps per reweighting")
      ->check(dsm::FlagInt());
  cli.add_option("--joint-irls-iterations", options->structure.joint_irls_iterations,
                 "with --joint-depth-pose-step: reweightings of the joint step per structure update")
      ->check(dsm::FlagInt());
  cli.add_flag("--joint-pose-pairs,!--no-joint-pose-pairs", options->structure.joint_step_pose_pairs,
               "with --joint-depth-pose-step: match the pairs within the pose radius, not only N(t)");
}

// The input pairs of joint mode's structure update (--structure-matching both).
void AddInputPairOptions(dsm::ToolCommandLine* command_line, dsm::EstimatorOptions* options) {
  dsm::ToolCommandLine& cli = *command_line;
  cli.add_flag("--cross-blurred-inputs,!--no-cross-blurred-inputs", options->cross_blurred_inputs,
               "joint, --structure-matching both: input pairs each blurred by the other frame's blur");
  cli.add_flag("--depth-input-pairs,!--no-depth-input-pairs", options->depth_input_pairs,
               "joint, --structure-matching both: the depth update matches the input pairs too (default "
               "on; off: restored pairs for depth, both kinds for poses)");
  cli.add_flag(
      "--recentred-depth-pass,!--no-recentred-depth-pass", options->recentred_depth_pass,
      "joint, --structure-matching both, with --depth-input-pairs: the last structure update ends with "
      "depth updates (--recentred-depth-passes) whose input pairs are re-centred on the shutter close "
      "(default on)");
  cli.add_option("--recentred-depth-passes", options->recentred_depth_passes,
                 "with --recentred-depth-pass: how many times the re-centring and the depth update "
                 "alternate (default 3)")
      ->check(dsm::FlagInt(1, 10));
  cli.add_option("--recentred-depth-cg-iterations", options->recentred_depth_cg_iterations,
                 "with --recentred-depth-pass: CG steps per reweighted system of each pass's depth update "
                 "(default 60)")
      ->check(dsm::FlagInt(1, 1000));
  cli.add_option("--recentred-depth-cg-tolerance", options->recentred_depth_cg_tolerance,
                 "with --recentred-depth-pass: each pass's CG stops once its residual is below this fraction "
                 "of the right-hand side's (0: all steps; default 0.005)")
      ->check(dsm::FlagNumber(0.0, 1.0));
  const std::map<std::string, dsm::DepthPreconditioner> preconditioners{
      {"none", dsm::DepthPreconditioner::kNone},
      {"jacobi", dsm::DepthPreconditioner::kJacobi},
      {"gauss-seidel", dsm::DepthPreconditioner::kTvGaussSeidel}};
  cli.add_option("--recentred-depth-preconditioner", options->recentred_depth_preconditioner,
                 "with --recentred-depth-pass: the passes' CG preconditioner, none, jacobi or gauss-seidel "
                 "(default gauss-seidel)")
      ->transform(CLI::CheckedTransformer(preconditioners));
  cli.add_option(
         "--equal-blur-tolerance", options->equal_blur_tolerance_px,
         "joint, --structure-matching both: pose-update pairs whose frames' blurs differ by less than "
         "this (HR px) match their input pair only (0: restored pairs always; default 0.5; off under a pose "
         "prior)")
      ->check(dsm::FlagNumber());
  cli.add_option(
         "--unequal-blur-tolerance", options->unequal_blur_tolerance_px,
         "joint, --structure-matching both: pairs whose frames' blurs differ by more than this (HR px) "
         "match their restored pair only, in the depth and the pose updates (0: input pairs always; default "
         "2)")
      ->check(dsm::FlagNumber());
  cli.add_option(
         "--equal-blur-input-weight", options->equal_blur_input_weight,
         "joint, --structure-matching both: an input pair's weight in the depth update where its "
         "frames' blurs are equal, falling to 0 at --unequal-blur-tolerance (0: every input pair at 1; "
         "default 1.5)")
      ->check(dsm::FlagNumber());
}

// Parses the command line into flags and options; false after --help.
bool ParseCommandLine(int argc, char** argv, Flags* flags, dsm::EstimatorOptions* options) {
  dsm::ToolCommandLine cli("estimate_sequence", kDescription);
  cli.add_option("--input", flags->input, "sequence folder (camera.yaml, frames.csv, images/)")
      ->required()
      ->check(CLI::ExistingDirectory);
  cli.add_option("--output", flags->output, "result folder to write")->required();
  cli.add_option("--mode", flags->mode, "joint or baseline")->check(CLI::IsMember({"joint", "baseline"}));
  cli.add_option("--scale", options->scale, "super-resolution factor")->check(dsm::FlagInt());
  cli.add_option("--iterations", options->max_iterations, "max_iter of Algorithm 1")->check(dsm::FlagInt());
  cli.add_option("--samples", options->samples,
                 "M, sub-exposure samples: the most a frame gets (each frame gets about one per HR pixel "
                 "of its blur, at least 4) unless --fixed-samples")
      ->check(dsm::FlagInt());
  cli.add_flag("--fixed-samples,!--adaptive-samples", flags->fixed_samples,
               "every frame gets M = --samples virtual cameras (default: adaptive M)");
  cli.add_option("--lambda-s", options->lambda_s, "self-consistency weight")->check(dsm::FlagNumber());
  cli.add_option("--lambda-d", options->structure.lambda_d, "depth TV weight")->check(dsm::FlagNumber());
  cli.add_option("--lambda-i", options->image.lambda_i, "image TV weight")->check(dsm::FlagNumber());
  cli.add_option("--threads", options->num_threads, "OpenMP threads, 0 = all cores")->check(dsm::FlagInt());
  cli.add_option("--neighbours", options->neighbour_radius, "N(t) radius")->check(dsm::FlagInt());
  cli.add_option("--pose-neighbours", options->pose_neighbour_radius, "pose update radius")
      ->check(dsm::FlagInt());
  cli.add_option("--source-occlusion-margin", options->visibility.source_depth_margin,
                 "Omega_ts also drops pixels of t behind D_s by more than this relative margin (0: off)")
      ->check(dsm::FlagNumber());
  cli.add_flag("--fixed-poses", flags->fixed_poses, "keep the initial poses");
  cli.add_flag("--gain-compensation,!--no-gain-compensation", options->gain_compensation,
               "estimate and divide out a per-frame gain (auto-gain), restore each image at its gain "
               "(default on)");
  AddInputPairOptions(&cli, options);
  AddJointStepOptions(&cli, options);
  AddDepthEdgeOptions(&cli, options);
  AddFusionOptions(&cli, options);
  AddDepthConsistencyOptions(&cli, options);
  AddMultiFrameDataOptions(&cli, options);
  AddDenoisedAnchorOptions(&cli, options);
  AddDepthSweepOptions(&cli, options);
  AddBlurPoseOptions(&cli, options);
  cli.add_option("--structure-matching", flags->structure_matching, "both, restored or blurred")
      ->check(CLI::IsMember({"both", "restored", "blurred"}));
  cli.add_option("--exposure", flags->exposure,
                 "auto: estimate the exposure from the blur (a fraction of the frame interval), "
                 "overriding frames.csv's")
      ->check(CLI::IsMember({"auto"}));
  cli.add_option("--readout-time", flags->readout_time,
                 "auto: measure the rolling shutter's readout time from the tracks (a fraction of the "
                 "frame interval, 0 for a global shutter), overriding sensor.yaml's")
      ->check(CLI::IsMember({"auto"}));
  cli.add_option("--noise-sigma", flags->noise_sigma,
                 "sensor noise of the frames, standard deviation in 8-bit gray levels, or auto: estimated "
                 "per window; sets the image TV weight (default auto)");
  cli.add_option("--output-scale", flags->output_scale, "bicubic up-sampling of the outputs, 1-4")
      ->check(dsm::FlagInt(1, 4));
  AddPosePriorOptions(&cli, flags, options);
  cli.add_option("--depth-confidence-threshold", flags->depth_confidence_threshold,
                 "depth whose confidence (depth_confidence/, in [0, 1]) is below this is written as NaN; "
                 "0 writes every depth (default 0.5)")
      ->check(dsm::FlagNumber(0.0, 1.0));
  AddWindowOptions(&cli, flags);
  cli.add_flag("--quiet", flags->quiet, "no progress bar, no summary line");
  if (!cli.Parse(argc, argv)) return false;
  options->mode = dsm::ParseEstimatorMode(flags->mode);
  options->structure_matching = dsm::ParseStructureMatching(flags->structure_matching);
  if (flags->fixed_poses) options->update_poses = false;
  options->adaptive_samples = !flags->fixed_samples;
  options->noise_sigma = ParseNoiseSigma(flags->noise_sigma);
  options->Check();
  flags->windowing.window_size = ParseWindowSize(flags->window_size);
  if (flags->windowing.window_size >= 0) CheckWindowing(flags->windowing);
  return true;
}

// The sequence as the estimator's input (and the camera's name).
dsm::EstimatorInput ReadInput(const std::string& input, std::string* camera_name) {
  const dsm::Sequence sequence = dsm::ReadSequence(input, /*read_ground_truth=*/false);
  if (sequence.frames.size() < 2) throw dsm::InputError(input + ": needs at least 2 frames");
  if (sequence.calibration.HasDistortion()) {
    throw dsm::InputError(input + "/camera.yaml: distortion is not zero; rectify the frames first");
  }
  *camera_name = sequence.calibration.camera_name;
  dsm::EstimatorInput estimator_input;
  estimator_input.camera = sequence.calibration.camera;
  estimator_input.frames = sequence.frames;
  estimator_input.readout_time = sequence.readout_time;  // sensor.yaml (0 without)
  for (const cv::Mat& image : sequence.images) estimator_input.images.push_back(dsm::ToFloat01(image));
  return estimator_input;
}

// Runs the estimator with a progress bar on stderr when it is a terminal.
dsm::EstimatorResult Estimate(const dsm::EstimatorOptions& options, const dsm::EstimatorInput& input,
                              const std::string& input_folder, const dsm::WindowedRunOptions& windowing,
                              bool quiet, std::vector<dsm::WindowRecord>* windows,
                              const dsm::WindowPreparation& prepare) {
  const bool draw = !quiet && isatty(STDERR_FILENO);
  dsm::ProgressCallback progress = [&](double fraction, const std::string& what) {
    if (!draw) return;
    const int width = 30;
    const int filled = static_cast<int>(fraction * width + 0.5);
    std::fprintf(stderr, "\r[%s%s] %3d%% %-40s", std::string(filled, '#').c_str(),
                 std::string(width - filled, '.').c_str(), static_cast<int>(fraction * 100 + 0.5),
                 what.c_str());
    std::fflush(stderr);
  };
  dsm::EstimatorResult result;
  try {
    result = dsm::EstimateInWindows(input, options, windowing, progress, windows, prepare);
  } catch (const dsm::InitializationError& error) {
    if (draw) std::fprintf(stderr, "\n");
    throw dsm::InputError(input_folder + ": initialisation failed: " + error.what());
  }
  if (draw) std::fprintf(stderr, "\n");
  return result;
}

// The exposure of every frame estimated from the blur (--exposure auto),
// written into `input`'s frames.
dsm::ExposureEstimate EstimateExposure(const dsm::EstimatorOptions& options, const std::string& input_folder,
                                       dsm::EstimatorInput* input) {
  try {
    const dsm::ExposureEstimate estimate =
        dsm::EstimateExposure(*input, options, dsm::ExposureEstimationOptions());
    for (size_t t = 0; t < input->frames.size(); ++t) input->frames[t].exposure = estimate.frame_exposures[t];
    return estimate;
  } catch (const dsm::InitializationError& error) {
    throw dsm::InputError(input_folder + ": exposure estimation: initialisation failed: " + error.what());
  }
}

// The readout time measured from the tracks (--readout-time auto), written
// into `input`; 0 (not measured) for a window without parallax.
dsm::ReadoutEstimate EstimateReadout(const dsm::EstimatorOptions& options, const std::string& input_folder,
                                     dsm::EstimatorInput* input) {
  try {
    const dsm::ReadoutEstimate estimate = dsm::EstimateReadoutTime(
        input->images, input->camera, input->frames, options.initializer, dsm::ReadoutSearchOptions());
    input->readout_time = estimate.seconds;
    return estimate;
  } catch (const dsm::NoParallaxError& error) {
    // A rotation: nothing to measure on; the estimate runs as a global shutter.
    dsm::ReadoutEstimate none;
    none.summary = std::string("not measured (") + error.what() + ")";
    input->readout_time = 0.0;
    return none;
  } catch (const dsm::InitializationError& error) {
    throw dsm::InputError(input_folder + ": readout estimation: initialisation failed: " + error.what());
  }
}

// --readout-time auto over the windows `ranges` cuts: each window's frames
// measure it (EstimateReadout); the sharpness-weighted median of the
// measurements, as the node takes it over its windows, is the sensor's and
// is written into `input`. One window: its measurement as it is.
dsm::ReadoutEstimate MeasureReadout(const dsm::EstimatorOptions& options, const std::string& input_folder,
                                    const std::vector<dsm::FrameRange>& ranges, dsm::EstimatorInput* input) {
  if (ranges.size() <= 1) return EstimateReadout(options, input_folder, input);
  std::vector<dsm::ReadoutEstimate> estimates;
  std::vector<std::pair<double, double>> samples;
  for (const dsm::FrameRange& range : ranges) {
    dsm::EstimatorInput window = dsm::WindowInputOf(*input, range);
    estimates.push_back(EstimateReadout(options, input_folder, &window));
    samples.emplace_back(estimates.back().seconds, estimates.back().sharpness);
  }
  // The report keeps the sharpest window's cost curve, with the seconds used.
  dsm::ReadoutEstimate combined =
      *std::max_element(estimates.begin(), estimates.end(),
                        [](const auto& a, const auto& b) { return a.sharpness < b.sharpness; });
  double per_second = 0.0;  // fraction per second: 1 / the frame interval
  for (const dsm::ReadoutEstimate& estimate : estimates) {
    if (estimate.seconds > 0.0) per_second = estimate.fraction / estimate.seconds;
  }
  combined.seconds = dsm::WeightedMedian(samples);
  combined.fraction = combined.seconds * per_second;
  combined.measured = combined.seconds > 0.0;
  std::string each;
  combined.elapsed_seconds = 0.0;
  for (const dsm::ReadoutEstimate& estimate : estimates) {
    combined.elapsed_seconds += estimate.elapsed_seconds;
    each += (each.empty() ? "" : ", ") + std::to_string(estimate.seconds) + " s";
  }
  combined.summary = "sharpness-weighted median of " + std::to_string(estimates.size()) +
                     " windows' measurements (" + each + "): " + std::to_string(combined.seconds) +
                     " s; the sharpest window: " + combined.summary;
  input->readout_time = combined.seconds;
  return combined;
}

// --exposure auto over windows: the first window's estimate, with each
// frame's exposure as the window that gave its outputs measured it, and the
// time of every window's measurement.
dsm::ExposureEstimate CombinedExposure(const std::vector<dsm::ExposureEstimate>& estimates,
                                       const std::vector<dsm::WindowRecord>& windows) {
  dsm::ExposureEstimate combined = estimates.front();
  if (estimates.size() <= 1 || estimates.size() != windows.size()) return combined;
  combined.frame_exposures.clear();
  combined.elapsed_seconds = 0.0;
  for (size_t w = 0; w < windows.size(); ++w) {
    combined.elapsed_seconds += estimates[w].elapsed_seconds;
    const int end = w + 1 < windows.size() ? windows[w + 1].first_output : windows[w].frames.last + 1;
    for (int t = windows[w].first_output; t < end; ++t) {
      combined.frame_exposures.push_back(estimates[w].frame_exposures[t - windows[w].frames.first]);
    }
  }
  combined.summary = "per window (" + std::to_string(windows.size()) + "); the first: " + combined.summary;
  return combined;
}

// With --exposure auto (`window_exposures` not empty): the combined
// estimate; the frames (for the result's frames.csv) get the exposures
// their outputs were estimated with, the timings the measurements' time.
std::optional<dsm::ExposureEstimate> UseExposures(const std::vector<dsm::ExposureEstimate>& window_exposures,
                                                  const std::vector<dsm::WindowRecord>& windows,
                                                  dsm::EstimatorInput* input, dsm::EstimatorResult* result) {
  if (window_exposures.empty()) return std::nullopt;
  dsm::ExposureEstimate exposure = CombinedExposure(window_exposures, windows);
  for (size_t t = 0; t < input->frames.size() && t < exposure.frame_exposures.size(); ++t) {
    input->frames[t].exposure = exposure.frame_exposures[t];
  }
  result->timings.insert(result->timings.begin(), {"exposure estimation", exposure.elapsed_seconds});
  return exposure;
}

// report.json's "readout_estimate" object (null without --readout-time auto).
dsm::Json ReadoutEstimateJson(const dsm::ReadoutEstimate& estimate) {
  dsm::Json cost = dsm::Json::array();
  for (const auto& point : estimate.cost) {
    cost.push_back({dsm::JsonNumber(point.first), dsm::JsonNumber(point.second)});
  }
  return {{"measured", estimate.measured},
          {"fraction", dsm::JsonNumber(estimate.fraction)},
          {"seconds", dsm::JsonNumber(estimate.seconds)},
          {"rms_px_by_fraction", cost},
          {"sharpness", dsm::JsonNumber(estimate.sharpness)},
          {"summary", estimate.summary}};
}

// report.json's "windows" array: the frames of each window, the first whose
// outputs it gave, how it continued the previous one, its energies' first
// and last totals.
dsm::Json WindowsJson(const std::vector<dsm::WindowRecord>& windows,
                      const std::vector<dsm::ExposureEstimate>& exposures) {
  dsm::Json list = dsm::Json::array();
  for (size_t w = 0; w < windows.size(); ++w) {
    const dsm::WindowRecord& window = windows[w];
    const double first = window.energies.empty() ? NAN : window.energies.front().total;
    const double last = window.energies.empty() ? NAN : window.energies.back().total;
    list.push_back({{"first_frame", window.frames.first},
                    {"last_frame", window.frames.last},
                    {"first_output_frame", window.first_output},
                    {"continued", window.continued},
                    {"note", window.note},
                    {"energy_first", dsm::JsonNumber(first)},
                    {"energy_last", dsm::JsonNumber(last)}});
    // With --exposure auto, the exposure fraction measured on its frames.
    if (w < exposures.size()) list.back()["exposure_fraction"] = dsm::JsonNumber(exposures[w].fraction);
  }
  return list;
}

// report.json's "exposure_estimate" object (null without --exposure auto).
dsm::Json ExposureEstimateJson(const dsm::ExposureEstimate& estimate) {
  dsm::Json frames = dsm::Json::array();
  for (double seconds : estimate.frame_exposures) frames.push_back(dsm::JsonNumber(seconds));
  dsm::Json correlation = dsm::Json::array();
  for (const auto& point : estimate.correlation)
    correlation.push_back({dsm::JsonNumber(point.first), dsm::JsonNumber(point.second)});
  return {{"measured", estimate.measured},
          {"fraction", dsm::JsonNumber(estimate.fraction)},
          {"seconds", dsm::JsonNumber(estimate.seconds)},
          {"frame_exposures", frames},
          {"correlation", correlation},
          {"summary", estimate.summary},
          {"elapsed_seconds", dsm::JsonNumber(estimate.elapsed_seconds)}};
}

// The result folder's images, depth maps and poses, up-sampled by output_scale.
void FillOutputs(const dsm::EstimatorResult& result, const std::vector<dsm::FrameRecord>& frames,
                 int output_scale, dsm::SequenceResult* out) {
  out->frames = frames;
  for (size_t t = 0; t < result.latent.size(); ++t) {
    if (output_scale > 1) {
      // "Proposed (w/o SR) + Bic.": the estimate at the input resolution,
      // bicubic up-sampled (depth as inverse depth, NaN kept out).
      out->latent.push_back(dsm::ToImage8(dsm::UpsampleBicubic(result.latent[t], output_scale)));
      cv::Mat inverse;
      cv::divide(1.0, result.depth[t], inverse);
      cv::patchNaNs(inverse, 0.0);
      cv::Mat inverse_up = dsm::UpsampleBicubic(inverse, output_scale), depth_up;
      cv::divide(1.0, inverse_up, depth_up);
      depth_up.setTo(std::numeric_limits<float>::quiet_NaN(), inverse_up <= 0.0f);
      out->depth.push_back(depth_up);
    } else {
      out->latent.push_back(dsm::ToImage8(result.latent[t]));
      out->depth.push_back(result.depth[t]);
    }
    out->poses.push_back({frames[t].stamp, result.T_world_cam[t]});
  }
}

// Confidence of every output depth pixel (ComputeDepthConfidence at the
// estimate's size, bilinearly resized to the output's), and the depth below
// `threshold` set to NaN. Returns the fraction of pixels left with depth.
double ApplyDepthConfidence(const dsm::EstimatorResult& result, const dsm::EstimatorOptions& options,
                            double threshold, std::vector<cv::Mat>* confidence, dsm::SequenceResult* out) {
  dsm::DepthConfidenceOptions confidence_options;
  confidence_options.neighbour_radius = options.neighbour_radius;
  confidence_options.visibility = options.visibility;
  confidence_options.threshold = threshold;
  *confidence = dsm::ComputeDepthConfidence(result.camera_hr, result.latent, result.depth, result.T_world_cam,
                                            confidence_options);
  double covered = 0.0;
  for (size_t t = 0; t < out->depth.size(); ++t) {
    cv::Mat& map = (*confidence)[t];
    if (map.size() != out->depth[t].size())
      cv::resize(cv::Mat(map), map, out->depth[t].size(), 0, 0, cv::INTER_LINEAR);
    out->depth[t] = dsm::MaskUnconfidentDepth(out->depth[t], map, threshold);
    covered += static_cast<double>(cv::countNonZero(out->depth[t] == out->depth[t])) / out->depth[t].total();
  }
  return out->depth.empty() ? 0.0 : covered / out->depth.size();
}

// OUT/depth_confidence/000000.tiff (float32 in [0, 1]), named like the depth maps.
void WriteConfidence(const std::string& output, const std::vector<dsm::FrameRecord>& frames,
                     const std::vector<cv::Mat>& confidence) {
  const std::string folder = output + "/depth_confidence";
  std::filesystem::create_directories(folder);
  for (size_t t = 0; t < confidence.size(); ++t) {
    const std::string path = folder + "/" + dsm::FrameStem(frames[t].index) + ".tiff";
    if (!cv::imwrite(path, confidence[t])) throw dsm::InputError(path + ": cannot write");
  }
}

// Stamps closer than this are one instant (as for gt/poses.txt, docs/file_formats.md).
constexpr double kStampTolerance = 1e-6;

std::string Seconds(double stamp) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.6f", stamp);
  return text;
}

// The prior pose at `stamp`: geodesic interpolation (InterpolatePose) between
// the two neighbouring prior poses; none outside the prior's time span.
std::optional<dsm::SE3> PriorPoseAt(const std::vector<dsm::StampedPose>& prior, double stamp) {
  if (stamp < prior.front().stamp - kStampTolerance || stamp > prior.back().stamp + kStampTolerance) {
    return std::nullopt;
  }
  const auto next = std::lower_bound(prior.begin(), prior.end(), stamp,
                                     [](const dsm::StampedPose& pose, double s) { return pose.stamp < s; });
  if (next == prior.end()) return prior.back().T_world_cam;
  if (next == prior.begin() || next->stamp - stamp <= kStampTolerance) return next->T_world_cam;
  const auto previous = next - 1;
  if (stamp - previous->stamp <= kStampTolerance) return previous->T_world_cam;
  const double alpha = (stamp - previous->stamp) / (next->stamp - previous->stamp);
  return dsm::InterpolatePose(previous->T_world_cam, next->T_world_cam, alpha);
}

// The prior pose of every frame at its stamp. InputError when the file is
// bad, its stamps do not increase, or no frame lies in its time span.
std::vector<std::optional<dsm::SE3>> ReadPriorAtFrames(const std::string& path,
                                                       const std::vector<dsm::FrameRecord>& frames) {
  const std::vector<dsm::StampedPose> prior = dsm::ReadTumTrajectory(path);
  for (size_t k = 1; k < prior.size(); ++k) {
    if (!(prior[k].stamp > prior[k - 1].stamp)) {
      throw dsm::InputError(path + ": pose " + std::to_string(k) + " has stamp " + Seconds(prior[k].stamp) +
                            ", not after the previous pose's " + Seconds(prior[k - 1].stamp) +
                            " (stamps must increase)");
    }
  }
  std::vector<std::optional<dsm::SE3>> at;
  bool any = false;
  for (const dsm::FrameRecord& frame : frames) {
    at.push_back(PriorPoseAt(prior, frame.stamp));
    any = any || at.back().has_value();
  }
  if (!any) {
    throw dsm::InputError(path + ": no prior pose in the frames' time span (frames " +
                          Seconds(frames.front().stamp) + " to " + Seconds(frames.back().stamp) +
                          " s, prior " + Seconds(prior.front().stamp) + " to " + Seconds(prior.back().stamp) +
                          " s)");
  }
  return at;
}

// Aligns the outputs' poses to the prior poses of their frames; when the
// alignment is valid, carries the poses into the prior's frame and the
// depths into its units, else leaves the outputs unchanged.
dsm::PriorAlignment ApplyPosePrior(const std::vector<std::optional<dsm::SE3>>& prior,
                                   dsm::SequenceResult* out) {
  std::vector<dsm::SE3> estimated, prior_poses;
  for (size_t t = 0; t < prior.size(); ++t) {
    if (!prior[t]) continue;
    estimated.push_back(out->poses[t].T_world_cam);
    prior_poses.push_back(*prior[t]);
  }
  const dsm::PriorAlignment alignment = dsm::AlignToPrior(estimated, prior_poses, dsm::PosePriorOptions());
  if (!alignment.valid) return alignment;
  for (dsm::StampedPose& pose : out->poses) {
    pose.T_world_cam = dsm::TransformPose(alignment.estimate_to_prior, pose.T_world_cam);
  }
  for (cv::Mat& depth : out->depth) depth = depth * alignment.estimate_to_prior.scale;  // new buffer
  return alignment;
}

// report.json's "pose_prior" object (scale, rms and scale_uncertainty null
// when not valid).
dsm::Json PosePriorJson(const std::string& file, const dsm::PriorAlignment& alignment) {
  const double scale = alignment.valid ? alignment.estimate_to_prior.scale : NAN;
  return {{"file", file},
          {"used", alignment.used},
          {"inliers", alignment.inliers},
          {"scale", dsm::JsonNumber(scale)},
          {"rms", dsm::JsonNumber(alignment.valid ? alignment.rms : NAN)},
          {"scale_uncertainty", dsm::JsonNumber(alignment.valid ? alignment.scale_uncertainty : NAN)},
          {"note", alignment.note},
          {"valid", alignment.valid}};
}

int Run(int argc, char** argv) {
  Flags flags;
  dsm::EstimatorOptions options;
  if (!ParseCommandLine(argc, argv, &flags, &options)) return 0;

  const auto start = std::chrono::steady_clock::now();
  std::string camera_name;
  dsm::EstimatorInput input = ReadInput(flags.input, &camera_name);
  const dsm::WindowedRunOptions windowing = Windowing(flags, input, options.scale);
  const std::vector<dsm::FrameRange> ranges =
      dsm::WindowRanges(static_cast<int>(input.images.size()), windowing);
  std::optional<dsm::ReadoutEstimate> readout;
  if (flags.readout_time == "auto") readout = MeasureReadout(options, flags.input, ranges, &input);
  // --exposure auto: measured on each window's frames before it is
  // estimated, as the node does (auto-exposure changes along a clip).
  std::vector<dsm::ExposureEstimate> window_exposures;
  dsm::WindowPreparation prepare;
  if (flags.exposure == "auto") {
    prepare = [&](int, dsm::EstimatorInput* window_input) {
      window_exposures.push_back(EstimateExposure(options, flags.input, window_input));
    };
  }
  std::vector<std::optional<dsm::SE3>> prior;
  if (!flags.pose_prior.empty()) {
    prior = ReadPriorAtFrames(flags.pose_prior, input.frames);
    input.T_prior_cam = prior;
  }
  std::vector<dsm::WindowRecord> windows;
  dsm::EstimatorResult result =
      Estimate(options, input, flags.input, windowing, flags.quiet, &windows, prepare);
  const std::optional<dsm::ExposureEstimate> exposure =
      UseExposures(window_exposures, windows, &input, &result);
  if (readout) result.timings.insert(result.timings.begin(), {"readout estimation", readout->elapsed_seconds});
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  dsm::SequenceResult out;
  out.calibration =
      dsm::CameraCalibration::FromCamera(result.camera_hr.Upscaled(flags.output_scale), camera_name);
  FillOutputs(result, input.frames, flags.output_scale, &out);
  std::vector<cv::Mat> confidence;
  const double depth_coverage =
      ApplyDepthConfidence(result, options, flags.depth_confidence_threshold, &confidence, &out);
  dsm::Json report = dsm::EstimateReportJson(options, flags.input, result, wall, PeakMemoryMiB());
  report["depth_confidence"] = {{"threshold", dsm::JsonNumber(flags.depth_confidence_threshold)},
                                {"coverage", dsm::JsonNumber(depth_coverage)}};
  report["exposure_estimate"] = exposure ? ExposureEstimateJson(*exposure) : dsm::Json();
  report["readout_estimate"] = readout ? ReadoutEstimateJson(*readout) : dsm::Json();
  report["window_size"] = windowing.window_size;
  report["windows"] = WindowsJson(windows, window_exposures);
  if (!flags.pose_prior.empty()) {
    const dsm::PriorAlignment alignment = ApplyPosePrior(prior, &out);
    report["pose_prior"] = PosePriorJson(flags.pose_prior, alignment);
    if (alignment.valid) {
      report["monocular_scale"] = "metric: poses in the pose prior's frame, depth in its units (metres)";
    } else {
      std::fprintf(stderr, "estimate_sequence: pose prior not used (%s); wrote the estimate unchanged\n",
                   alignment.note.c_str());
    }
  }
  out.report_json = dsm::JsonText(report);
  dsm::WriteResult(flags.output, out);
  WriteConfidence(flags.output, input.frames, confidence);
  if (!flags.quiet) {
    if (windows.size() > 1) {
      std::printf("estimate_sequence: %zu frames in %zu windows, %s, %.1f s, peak %.0f MiB; wrote %s\n",
                  result.latent.size(), windows.size(), dsm::ToString(options.mode), wall, PeakMemoryMiB(),
                  flags.output.c_str());
    } else {
      std::printf("estimate_sequence: %zu frames, %s, %.1f s, peak %.0f MiB, energy %.4g -> %.4g; wrote %s\n",
                  result.latent.size(), dsm::ToString(options.mode), wall, PeakMemoryMiB(),
                  result.energies.front().total, result.energies.back().total, flags.output.c_str());
    }
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  deblur_sr_mvs::KeepFreedMemoryForReuse();
  return deblur_sr_mvs::ToolMain("estimate_sequence", Run, argc, argv);
}
