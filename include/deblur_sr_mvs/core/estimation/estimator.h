// The joint estimator: Algorithm 1 of the paper end to end on a window of
// frames (initialisation, then max_iter times: image update, structure
// update, visibility update).
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/estimation/depth_consistency.h"
#include "deblur_sr_mvs/core/estimation/depth_edges.h"
#include "deblur_sr_mvs/core/estimation/depth_sweep.h"
#include "deblur_sr_mvs/core/estimation/image_update.h"
#include "deblur_sr_mvs/core/estimation/initializer.h"
#include "deblur_sr_mvs/core/estimation/photometric.h"
#include "deblur_sr_mvs/core/estimation/structure_update.h"
#include "deblur_sr_mvs/core/estimation/denoised_anchor.h"
#include "deblur_sr_mvs/core/estimation/input_denoising.h"
#include "deblur_sr_mvs/core/estimation/multi_frame_data.h"
#include "deblur_sr_mvs/core/estimation/temporal_fusion.h"
#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/frame_types.h"
#include "deblur_sr_mvs/core/geometry/se3.h"
#include "deblur_sr_mvs/core/geometry/sim3.h"
#include "deblur_sr_mvs/core/geometry/visibility.h"
#include "deblur_sr_mvs/core/imaging/capture_operator.h"

namespace deblur_sr_mvs {

enum class EstimatorMode {
  kJoint,     // the proposed method
  kBaseline,  // no capture operator, images fixed to bicubic ("Bic. + Baseline")
};
const char* ToString(EstimatorMode mode);

// What the structure update (Sec. optDepthAndCamera) matches.
enum class StructureMatching {
  // The paper: B_t against Psi_t applied to I_s warped into t (the LR blurry
  // observation), plus the self-consistency term linearised in depth.
  kBlurred,
  // I_t against I_s warped into t, both restored HR latent images. Sharp
  // images locate structure far more precisely than blurry LR ones once the
  // image update has deblurred them (Dolls: depth rel. error 0.0106 vs
  // 0.0183 with kBlurred). But the latent images were fitted with the
  // current structure: an error in D_t or P_t changes the blur that Psi_t
  // assumes, and I_t shifts to absorb part of it (a blur that is too long
  // moves the restored image by about half the excess). Matching the
  // restored images alone then sees only part of the error, and the
  // structure barely leaves its initialisation along those directions.
  kRestored,
  // Default: every pair twice, on the restored images (precise) and on the
  // bicubic up-sampled inputs (blurry, but independent of the current
  // structure), as one IRLS problem (EstimatorOptions::depth_input_pairs
  // can keep the input pairs out of the depth update). On the four benchmark scenes this
  // lowers the mean ATE from 0.00067 to 0.00056 m and the mean depth rel.
  // error from 0.0174 to 0.0170 against kRestored (BENCHMARKS.md).
  kRestoredAndInput,
};
const char* ToString(StructureMatching matching);
StructureMatching ParseStructureMatching(const std::string& text);
// "joint" | "baseline"; throws InputError otherwise.
EstimatorMode ParseEstimatorMode(const std::string& text);

// EstimatorOptions::model_error_sigma's default, fitted on the benchmark
// scenes (BENCHMARKS.md "Noise").
constexpr double kModelErrorSigma = 1.0 / 255.0;

// A capture operator Psi_t sampling I_src (eq:blurOperator) and the LR
// mask of its term: full coverage and, for src != t, Omega_{t,src}.
struct MaskedOperator {
  CaptureOperator op;
  cv::Mat mask;  // LR CV_8UC1, 255 where the term counts
};

// An operator handed from one window of a stream to the next, with what it
// was built from: the next window uses it instead of building one only when
// its frame structure and options are the same bit for bit
// (SameCaptureGeometry, SameOperatorModel), so that the build would give the
// same operator.
struct CarriedOperator {
  CaptureGeometry geometry;  // depth_hr shallow: the estimator replaces depth maps, never writes into them
  CaptureOperatorOptions options;
  VisibilityOptions visibility;  // of the mask
  std::shared_ptr<const MaskedOperator> entry;
};
using CarriedOperators = std::vector<CarriedOperator>;

struct EstimatorOptions {
  EstimatorMode mode = EstimatorMode::kJoint;
  int scale = 2;     // super-resolution factor (1: "w/o SR")
  int samples = 50;  // M of eq:blurOperator; with adaptive_samples, the cap
  // Adaptive M: each frame's operators get about one virtual camera per HR
  // pixel of that frame's blur, between 4 and `samples`
  // (CaptureOperatorOptions::adaptive_samples).
  bool adaptive_samples = true;
  int max_iterations = 3;    // max_iter of Algorithm 1
  int neighbour_radius = 1;  // N(t) = frames within this distance of t
  // The pose update matches frames up to this far apart (at least N(t)):
  // longer baselines constrain the translations better, and the pose
  // update is cheap next to the image update. kBlurred uses N(t) only.
  int pose_neighbour_radius = 2;
  double lambda_s = 30.0;    // self-consistency weight (eq:IPterm)
  ImageUpdateOptions image;  // lambda_i and the IRLS/CG budget
  // Sensor noise of the LR frames: its standard deviation in intensity
  // units (frames in [0, 1]); negative: estimated per window from the frames
  // (EstimateNoiseSigma). The image update's weights follow it
  // (NoiseAwareImageOptions), so that it does not amplify the noise.
  double noise_sigma = -1.0;
  // The residual that the data terms see on noise-free frames (model error:
  // warps, blur model, quantisation), in intensity units: image.lambda_i is
  // the weight for it, and the noise adds to it (NoiseAwareImageOptions).
  double model_error_sigma = kModelErrorSigma;
  StructureUpdateOptions structure;  // lambda_d and the IRLS/GN budget
  VisibilityOptions visibility;
  InitializerOptions initializer;
  bool update_poses = true;  // false keeps the initial poses
  // With a pose prior (EstimatorInput::T_prior_cam and
  // initializer.pose_prior_position_sigma > 0): the structure update's pose
  // steps (UpdatePoses, the joint depth + pose step) carry the prior's
  // centres and orientations as Huber terms with the initialiser's sigmas
  // (PosePriorTerms), in the world of the structure the window starts from,
  // carried there by the robust Sim(3) of its poses to the prior. Without
  // them the iterations keep the initialiser's scale only through the
  // depth, and move along the bas-relief direction (a rotation traded for a
  // shift of the inverse depths) by a few percent of the depth in metres
  // (BENCHMARKS.md "The pose prior in the joint iterations"). false: only
  // the initialisation and the output alignment use the prior.
  bool pose_prior_in_iterations = true;
  // The weight of those terms against the photometric ones: 1 treats every
  // matched value of the pose update as an independent observation
  // (Laplace, scale = the mean absolute residual), which overstates the
  // photometric evidence by orders of magnitude (neighbouring values, the
  // pairs that share a frame, and the restored and input pair of each are
  // far from independent), so that the prior then changes nothing. The
  // default is measured (BENCHMARKS.md "The pose prior in the joint
  // iterations").
  double pose_prior_weight = 1e4;
  // Feature tracks as pose evidence (joint mode; TrackPoseTerms): the
  // reprojection errors of the initialiser's tracks (EstimatorInput::tracks),
  // observed at mid-exposure (of their row) on the estimator's blur path, each track's point
  // eliminated, in the pose steps of every structure update, in units of the
  // photometric terms as pose_prior_weight; 0: off. They do not depend on
  // the depth maps nor on the blur model within the exposure. Gated per
  // structure update: with c the tracks' cost at the current poses and
  // c_min its least value over the poses, the weight is multiplied by
  // clamp((c / c_min - 1 - gate_start) / gate_width, 0, 1). Where the dense
  // iterations' poses explain the tracks nearly as well as the tracks' own
  // optimum (c / c_min 1.03-1.13 on the benchmark's lateral, arc and forward
  // paths, whose dense poses are more accurate than the tracks') they are
  // left alone; on hand-held, gain and rolling-shutter paths the dense
  // iterations leave c / c_min at 1.3-2.6, and the tracks pull the poses
  // back (BENCHMARKS.md "Feature tracks as pose evidence").
  double track_pose_weight = 1000.0;
  double track_pose_sigma_px = 0.5;  // the tracks' noise, LR px (Huber above 2 sigma)
  double track_pose_gate_start = 0.2;
  double track_pose_gate_width = 0.5;
  // Leading frames whose poses the structure update holds (>= 1: frame 0 is
  // the gauge). The stream holds the frames shared with the previous window,
  // which then also fixes the scale.
  int fixed_leading_poses = 1;
  // Leading frames whose latent images stay as given
  // (EstimatorInput::initial_latents, which each of them needs): the stream's
  // frames shared with the previous window, which restored them and already
  // gave them out. Their image updates are skipped; the images still enter
  // the other frames' terms and the energy. Their depth maps are updated:
  // holding them too (from the previous window, where the shared frames sat
  // at its end with neighbours on one side) doubled the stitched ATE in
  // test/core/estimation/stream_test.cc (0.00117 against 0.00066 m).
  int held_leading_latents = 0;
  // Stream: the result keeps (EstimatorResult::carried_operators) the
  // capture operators that the next window, which shares this window's last
  // `carried_frames` frames, can use as they are: Psi_t sampling I_src with
  // t, src and the frames of t's blur path (BlurPathFrames: t - 1 and t + 1)
  // all among those frames, t not the last frame (its path gains the frame
  // after it in the next window). The first shared frame is the next
  // window's frame 0, whose path runs to its next two frames instead, so at
  // least 3 shared frames are needed for any reuse. Kept only with
  // keep_input_gauge, in whose world the next window receives the
  // structure. 0: none.
  int carried_frames = 0;
  // A continued stream window (StreamEstimator::Process with frames shared
  // with the previous window, whose poses, depths and images start it warm):
  // the joint depth + pose step's reweightings and CG steps per reweighting
  // there, in place of structure.joint_irls_iterations /
  // structure.joint_cg_iterations. 0: the same as in any window.
  int continued_joint_irls_iterations = 0;
  int continued_joint_cg_iterations = 0;
  // ... the pose update's Gauss-Newton steps there (0: structure.pose_iterations)
  int continued_pose_iterations = 0;
  // ... and the iterations of Algorithm 1 there (-1: max_iterations).
  int continued_max_iterations = -1;
  // ... and the re-centred depth passes there (0: recentred_depth_passes).
  // One pass instead of three saves about a tenth of the node's continued
  // 320x240 window for +0.5-0.9 % crop and +3 % (up to +11 %) full-frame
  // depth error, two passes half that for +1 % (BENCHMARKS.md "Fewer
  // re-centred passes in continued windows"; measured while the passes
  // still updated the held frames too, see below): not the default.
  int continued_recentred_depth_passes = 0;
  // Whether the re-centred depth passes also update the held leading
  // frames' depth (held_leading_latents: a continued window's frames shared
  // with the previous window, given out with it). false: they keep the
  // depth the last pose update left; their re-centred inputs still serve
  // the other frames' pairs, which is all their passes reached. Leaving
  // them out saves a third of the passes of the node's continued windows
  // (6 frames, 2 held): about 2 of 6 depth-update thread-seconds, 5 % of a
  // continued 320x240 window's CPU, for +0.2 % crop and +0.15 % full-frame
  // depth error on average (worst +0.8 %) and no change of PSNR or ATE over
  // 29 streams (BENCHMARKS.md "Re-centred passes skip the held frames").
  bool recentred_passes_on_held_frames = false;
  // Output gauge (docs/file_formats.md#monocular-scale). false: world = the
  // first camera, monocular scale such that the median scene depth of the
  // window is 1 unit. true: the world and scale of the structure given to
  // RunFromStructure / RunRotationOnly (the stream continues its own world).
  bool keep_input_gauge = false;
  bool update_structure = true;  // false: images only (depth and poses fixed)
  StructureMatching structure_matching = StructureMatching::kRestoredAndInput;
  // With kRestoredAndInput in joint mode: the input pairs of the structure
  // update become cross-blurred (B_t through s's blur against B_s through
  // t's blur, CrossBlurGeometry, rebuilt at every structure update from the
  // current depth and poses), so that both images of a pair carry the same
  // blur on paths whose frames move differently (hand-held, arc); the plain
  // bicubic inputs assume equal blur. It needs the capture model: the
  // baseline keeps the plain inputs. Off: it lowers the hand-held depth
  // error but raises the depth error on lateral and forward paths (the
  // second blur removes detail) and the ATE on every path measured
  // (BENCHMARKS.md "Method ablation").
  bool cross_blurred_inputs = false;
  // kRestoredAndInput only: whether the depth update matches the input pairs
  // too (true, default), or the restored pairs alone while the pose update
  // keeps both (false). Off lowers joint's per-frame median-scaled depth
  // error against the baseline from 0.92x to 0.87x on average over 8
  // sequences of 4 path types, but the depth maps lose their common scale:
  // with an exact pose prior the depth in metres is 1.46x the scale-aligned
  // figure instead of 1.07x, and a rotate-then-translate stream's worst
  // orientation error rises from 0.15 to 0.66 deg (BENCHMARKS.md "Method
  // ablation"). So it stays on.
  bool depth_input_pairs = true;
  // kRestoredAndInput with depth_input_pairs (and not cross_blurred_inputs):
  // the last structure update ends, after its pose update, with one more
  // depth update per frame whose input pairs are re-centred on the shutter
  // close (RecentreOnShutterClose at the current depth and poses; the pixels
  // of t whose mid-exposure point leaves the image are left out). A blurred
  // frame is centred on its mid-exposure camera, while the latent image, D_t
  // and the warps are the close camera's, so at depth edges the plain inputs
  // match content half a blur away from where D_t puts it. The poses are
  // left as they are: re-centred pairs in the joint step or the pose update
  // move them more than they mend (the re-centring carries D_t's own error),
  // and beside plain pairs the two kinds disagree on the poses. On seeds 4
  // and 5 of the benchmark (24 sequences each) joint's crop depth error
  // falls from 0.756x to 0.745x and from 0.780x to 0.770x the baseline's,
  // full frame 0.878x -> 0.862x and 0.881x -> 0.865x, the poses unchanged,
  // +0.02-0.03 dB; a pass after every structure update lowers the depth
  // error a little more but moves the poses (BENCHMARKS.md "Input pairs
  // re-centred on the shutter close").
  bool recentred_depth_pass = true;
  // With recentred_depth_pass: how many times the re-centring and the depth
  // update alternate. Each re-centring starts from the depth the last update
  // left, so the next one re-samples the inputs at a depth nearer the truth.
  // On the benchmark's seed 0 (24 sequences) joint's crop depth error falls
  // by 0.8 % with 2 passes against 1 and by 1.3 % with 3 (full frame 1.2 /
  // 2.1 %), the poses unchanged, +0.01 dB; 5 passes gain 0.5 % more on 8 of
  // them. Each pass cost about 2.5 % of a run's CPU with the structure
  // update's CG stop, a little more with the passes' own (below)
  // (BENCHMARKS.md "Re-centred depth passes").
  int recentred_depth_passes = 3;
  // With recentred_depth_pass: each pass's depth update solves its
  // reweighted systems (CG on the normal equations of eq:taylorExpansion)
  // in at most this many steps, or fewer once the residual is below this
  // fraction of the right-hand side's norm: tighter than the structure
  // update's own (StructureUpdateOptions::depth_cg_iterations 15,
  // depth_cg_tolerance 0.05), whose steps the next reweighting or
  // iteration takes further; the passes end the estimation. 60 /
  // 0.005 against 15 / 0.05 on 48 benchmark sequences (seeds 0, 4, 5):
  // full-frame depth error 0.92x (lower on all 48), crop 0.99x (up by at
  // most 1.4 % on 11), poses unchanged, +0.02-0.04 dB, about 2-3 % more
  // time; 200 / 0.001 another 0.96x full frame at 11-13 % more time
  // (BENCHMARKS.md "The re-centred passes solved further").
  int recentred_depth_cg_iterations = 60;
  double recentred_depth_cg_tolerance = 0.005;
  // With recentred_depth_pass: the passes' CG preconditioner. The TV
  // Gauss-Seidel sweeps reach the tolerance in about a third of plain CG's
  // steps (which rarely reaches it in 60), and at the border, which the
  // TV term alone reaches, solve as far as 200 / 0.001 did
  // (BENCHMARKS.md "Gauss-Seidel sweeps in the re-centred passes").
  DepthPreconditioner recentred_depth_preconditioner = DepthPreconditioner::kTvGaussSeidel;
  // kRestoredAndInput in joint mode: in the pose update, a pair (t <- s)
  // whose frames' blurs differ by less than this many HR pixels
  // (BlurDifferenceHr at the current structure) matches its input pair
  // only. Two frames that move alike carry the same blur, so their
  // up-sampled inputs compare without bias, while the restored images were
  // fitted to the current poses and partly absorb a pose error. Where the
  // blurs differ (hand-held, forward) the inputs are biased and the restored
  // pair stays. 0: the restored pairs always. Off where a pose prior enters
  // the structure update: in the node's windows (4 frames at 96x72) with an
  // exact prior the rule took the depth in metres from 1.06x to 1.18x the
  // scale-aligned error, past issue 11's 1.1x. Default 0.5 with
  // unequal_blur_tolerance_px 2 and joint_coarse_levels 1: on the 96
  // benchmark sequences of four seeds, depth below the baseline's on 96
  // (88 without the two rules), ATE at or below it on 68 (60), +0.09 to
  // +0.39 dB per seed; forward ATE at or below on 6 of 16 (9)
  // (BENCHMARKS.md "The two blur rules by default").
  double equal_blur_tolerance_px = 0.5;
  // kRestoredAndInput in joint mode: the counterpart. A pair (t <- s) whose
  // frames' blurs differ by more than this many HR pixels (BlurDifferenceHr
  // at the current structure) matches its restored pair only, in the depth
  // update, the joint depth + pose step and the pose update: its up-sampled
  // inputs carry different blurs and compare with a bias. Above
  // equal_blur_tolerance_px where both are on. 0: the input pairs always.
  // Default 2: only hand-held, gain-jitter and rolling-shutter pairs differ
  // by that much (lateral, arc and forward pairs by 0.5-1.8 px); there the
  // depth error falls by up to 14 % and the images gain up to 1.1 dB
  // (measurements with equal_blur_tolerance_px above; BENCHMARKS.md
  // "Unequal blur: restored pairs only").
  double unequal_blur_tolerance_px = 2.0;
  // kRestoredAndInput in joint mode, with unequal_blur_tolerance_px on: the
  // weight of an input pair in the depth update and the joint depth + pose
  // step (PairMatching::weight) follows how far its two frames' blurs agree,
  // w (1 - d / unequal_blur_tolerance_px) for a blur difference of d HR px
  // (BlurDifferenceHr at the current structure; 1 where it is NaN): w where
  // the blurs are equal, falling to 0 where the pair is dropped. The pose
  // update keeps every input pair at 1. 0: every input pair at 1 (before
  // 2026-12-06). Default 1.5: on the 24 benchmark sequences of each of
  // seeds 4, 3 and 0, full-frame depth error 0.917x -> 0.910x, 0.910x ->
  // 0.897x, 0.931x -> 0.902x the baseline's, ATE at or below it on 22 (21),
  // 16 (14), 22 (20), depth below it on all 24; with 2, arc / Aloe (its
  // turn missed) rose above the baseline (BENCHMARKS.md "How much the input
  // pairs weigh in the depth update").
  double equal_blur_input_weight = 1.5;
  // Joint mode: blur as motion evidence. The pose update also takes the
  // self-consistency term lambda_s |B_t - Psi_t I_t| (eq:IPterm) linearised
  // in the poses that fix Psi_t's blur path (P_t and its neighbours,
  // eq:interpolatingP), so that the blur's length and direction in B_t
  // constrain the motion (LinearizeBlurInPoses; its sampling and weight:
  // StructureUpdateOptions::blur_pose_*). The baseline has no capture model
  // and ignores it. Off: on 8 sequences (Dolls, Aloe x lateral, arc,
  // forward, hand-held) the self term raises the ATE from 0.85x to 1.11x the
  // baseline's (I_t was fitted to B_t through the current blur, so the term
  // holds the poses where the last image update left them), and the pairs
  // form gives 0.89x (weight 1) / 0.87x (0.3) at depth 0.92x / 0.91x against
  // 0.91x without; neither finds the arc's turn (BENCHMARKS.md "Blur as
  // motion evidence in the pose update").
  bool blur_pose_evidence = false;
  // Depth edges (issue 14): an edge-aware weighted median of each output
  // D_t guided by its latent image (RefineDepthEdges), against the fattening
  // of foreground depth onto the background. On (radius 8, the output
  // only; a stream refines the frames it publishes): see DepthEdgeOptions
  // and BENCHMARKS.md "Depth edges on in the library and the node".
  DepthEdgeOptions depth_edges;
  // Temporal fusion of the output images (issue 12, noise): joint mode
  // fuses each restored I_t with its neighbours' restored images warped
  // into t by the final depth and poses (FuseRestoredImages), after the
  // last image update and the output depth (depth, poses and energies are
  // unchanged).
  // Not the held leading latents (a stream's, already fused). On by default
  // in the library, so in the node too (it runs this Estimator): see
  // TemporalFusionOptions and BENCHMARKS.md "Temporal fusion of the
  // restored images". radius 0 turns it off.
  TemporalFusionOptions fusion;
  // Consistency between the depth maps of neighbouring frames (issue 14):
  // each output D_t replaced, where neighbours' depth maps agree with it
  // within a tolerance, by the mean of the agreeing inverse depths
  // (DepthConsistencyOptions), after the output depth's edge refinement and
  // the gauge's scale; poses and images are unchanged. Both modes (it uses
  // only depth and poses). Not over a stream's held leading frames (given
  // out with the previous window); the next window starts from the solver's
  // depth (EstimatorResult::solver_depth). Off by default in the library
  // (radius 0; DepthConsistencyOptions::radius says why), on in
  // estimate_sequence and the node: BENCHMARKS.md "Consistency between
  // neighbouring depth maps".
  DepthConsistencyOptions depth_consistency;
  // Multi-frame data pass (issue 12, noise): joint mode re-solves each
  // restored I_t after the last image update, with the final depth and
  // poses, its agreeing neighbours' matching terms raised towards lambda_s
  // (MultiFrameDataOptions), before the temporal fusion; depth, poses and
  // energies are unchanged. On by default (relative_weight 1; 0 turns it
  // off): BENCHMARKS.md "Multi-frame evidence in the last image pass".
  MultiFrameDataOptions multi_frame_data;
  // Denoised anchor (issue 12, noise): in joint mode, where the window's
  // noise estimate (noise_sigma) lies above the estimator's floor, the
  // multi-frame data pass also pulls each I_t towards its non-local-means
  // denoised copy (a plug-and-play step; DenoisedAnchorOptions), frame 0
  // included; on noise-free frames nothing changes. Off by default: it lost
  // PSNR at sigma 1-4 (BENCHMARKS.md, branch noise7).
  DenoisedAnchorOptions denoised_anchor;
  // Input denoising (issue 12, noise): Run filters the frames with
  // multi-frame non-local means at a strength that follows the noise
  // estimate above the estimator's floor (InputDenoisingOptions), then
  // estimates from them; noise-free frames are not touched. Run only (not
  // RunFromStructure, so not the stream or the node).
  InputDenoisingOptions input_denoising;
  // Depth re-sweep (issue 14): joint mode's output D_t re-estimated by a
  // plane sweep over the restored images with guided-filter cost
  // aggregation where it clearly disagrees with the solver's
  // (SweepInverseDepth), before the depth-edge median; the output only (not
  // a stream's held leading frames). Off in the library, on in
  // estimate_sequence and the node (crop depth 0.874x -> 0.799x the
  // baseline's on 8 sequences, +8 % CPU): see DepthSweepOptions.
  DepthSweepOptions depth_sweep;
  int num_threads = 0;  // OpenMP threads for every stage; 0 = default
  // Wall-time cap of one run (s): no outer iteration starts after it, the
  // last accepted state is returned and the cap is noted (0: no cap). Every
  // inner stage is capped by its own iteration counts (image.*, structure.*,
  // initializer.*).
  double max_seconds = 0.0;
  // Auto-gain (issue 12, docs/file_formats.md#report `frame_gains`): every
  // frame is divided by its gain relative to the window's first frame
  // (EstimateFrameGains) before the estimation, so that the brightness
  // constancy of eq:matchingTerm holds, and its restored latent image is
  // multiplied by it afterwards (each output keeps its frame's brightness).
  // With +-10 % jitter it removes nearly all the damage, and without
  // auto-gain it measures no worse on the benchmark sequences (BENCHMARKS.md
  // "Gain compensation", "Gain compensation on by default"; the tests of
  // gain_test.cc). On by default: most cameras have auto-gain.
  bool gain_compensation = true;
  GainEstimationOptions gain;  // the robust ratio's corners, box, thresholds
  void Check() const;          // throws InputError naming the bad value
};

struct EstimatorInput {
  std::vector<cv::Mat> images;      // LR frames, float in [0, 1], 1 or 3 channels
  PinholeCamera camera;             // intrinsics of the LR frames
  std::vector<FrameRecord> frames;  // stamps (shutter close) and exposures
  // Rolling shutter (docs/file_formats.md#rolling-shutter): LR row y of H
  // opens y * readout_time / H after row 0; stamps are row 0's. 0: global.
  double readout_time = 0.0;
  // Warm start (the stream): per frame, the HR latent image I_t the image
  // update starts from, of the HR size and the frames' channel count; an
  // empty entry (or a shorter vector) starts from the bicubic up-sampling.
  std::vector<cv::Mat> initial_latents;
  // Operators of the previous window of a stream (its
  // EstimatorResult::carried_operators): one is used instead of a build
  // only where it was built from the same structure and options.
  CarriedOperators carried_operators;
  // Pose prior (docs/file_formats.md#monocular-scale): empty, or per frame
  // T_prior_cam at its stamp, none where the prior has no pose. The
  // initialisation adjusts the structure to it (InitializerOptions::
  // pose_prior_position_sigma); the output gauge stays as without it.
  std::vector<std::optional<SE3>> T_prior_cam;
  // With T_prior_cam: the similarity that carries this window's world to
  // the prior's frame, when the caller knows it already. Set: the prior's
  // terms in the structure update carry the prior through it; none: through
  // the robust Sim(3) of this window's poses (AlignToPrior). A stream's
  // continued windows with depth leave it unset (StreamEstimator::
  // ContinueTrajectory says why); its rotation-only windows place their
  // cameras by the stream's fit (StreamEstimator::PlaceOnPrior).
  std::optional<Sim3> world_to_prior;
  // The initialiser's feature tracks (InitialStructure::tracks), pixels of
  // `camera`: Estimator::Run sets them from its own initialisation; a caller
  // of RunFromStructure may pass them (EstimatorOptions::track_pose_weight).
  std::vector<FeatureTrack> tracks;
};

// Energy of eq:energyFunction at one point of the algorithm.
struct EnergyRecord {
  int iteration = 0;  // 0 = after initialisation
  std::string stage;  // "initialization" | "image" | "structure"
  double total = 0.0;
  double matching = 0.0;          // sum_t E_t^m
  double self_consistency = 0.0;  // sum_t E_t^s (includes lambda_s)
  double image_tv = 0.0;          // lambda_i sum_t TV(I_t)
  double depth_tv = 0.0;          // lambda_d sum_t TV_g(D_t)
};

struct StageTiming {
  std::string stage;
  double seconds = 0.0;
};
// Adds `seconds` to stage `stage` of `timings`, appended when new (first-seen order).
void AddStageSeconds(const std::string& stage, double seconds, std::vector<StageTiming>* timings);

struct EstimatorResult {
  PinholeCamera camera_hr;
  std::vector<cv::Mat> latent;   // HR, float in [0, 1]
  std::vector<cv::Mat> depth;    // HR CV_32FC1, NaN invalid, scale as the poses
  // The solver's own D_t in the same gauge, before the output's refinements
  // (depth_sweep, depth_edges, depth_consistency): what the window's
  // operators were built with, and what a stream's next window starts from
  // for the frames it shares. Empty where the run has no depth solver
  // (RunRotationOnly: `depth` is all NaN).
  std::vector<cv::Mat> solver_depth;
  std::vector<SE3> T_world_cam;  // in the output gauge (EstimatorOptions::keep_input_gauge)
  // False for a window without parallax (RunRotationOnly): the depth maps
  // are all NaN and every camera keeps one translation.
  bool depth_observable = true;
  std::vector<EnergyRecord> energies;
  std::vector<StageTiming> timings;
  std::string initializer_summary;
  // What the solver had to do beyond the plan: an iteration undone because it
  // raised (or lost) the energy, the time cap.
  std::vector<std::string> notes;
  // Per frame the gain relative to the first that the input was divided by
  // (EstimatorOptions::gain_compensation); empty when compensation is off.
  std::vector<double> frame_gains;
  // The noise level the window was estimated with (EstimatorOptions::
  // noise_sigma, or its estimate; intensity units) and the image TV weight
  // it gave (NoiseAwareImageOptions).
  double noise_sigma = 0.0;
  double image_lambda_i = 0.0;
  // The input denoising's filter strength h (intensity units; 0: the
  // frames were not filtered, EstimatorOptions::input_denoising).
  double input_denoising_h = 0.0;
  // Operators for the next window (EstimatorOptions::carried_frames), and
  // how many of the input's carried operators this run used instead of
  // building them.
  CarriedOperators carried_operators;
  int operators_reused = 0;
  // The work of the image solves, summed over the updates of the window
  // (ImageUpdateStats).
  ImageUpdateStats image_work;
};

// The image update's options for frames with noise of `noise_sigma`
// (intensity units). eq:imgUpdate's L1 data terms are the MAP data term of
// Laplacian residuals, |r| / b with b proportional to their standard
// deviation; relative to them the TV prior's weight is lambda_i * b. The
// residual is the model error (options.model_error_sigma, for which
// options.image.lambda_i was chosen) plus the independent sensor noise, so
// b grows as sqrt(model_error_sigma^2 + noise_sigma^2), and so does lambda_i:
//   lambda_i(noise) = lambda_i * sqrt(1 + (noise_sigma / model_error_sigma)^2).
// Noise-free frames (noise_sigma well below model_error_sigma) keep lambda_i.
ImageUpdateOptions NoiseAwareImageOptions(const EstimatorOptions& options, double noise_sigma);

// Progress: (fraction done in [0, 1], what is running).
using ProgressCallback = std::function<void(double, const std::string&)>;

// Thrown by Estimator::Run/RunFromStructure when the cancel flag was raised
// (the node's shutdown): the run stops at the next frame or stage boundary.
class EstimationCancelled : public std::runtime_error {
 public:
  EstimationCancelled() : std::runtime_error("estimation cancelled") {}
};

// Thrown when the energy is not finite before any iteration could be undone
// (e.g. a degenerate initial structure): the window cannot be estimated.
class EstimationDiverged : public std::runtime_error {
 public:
  explicit EstimationDiverged(const std::string& what) : std::runtime_error(what) {}
};

// Median of the finite positive values of all the depth maps (0 when there
// are none): the monocular scale of docs/file_formats.md#monocular-scale.
double MedianDepth(const std::vector<cv::Mat>& depths);

// What the notes (and the node's status) say of a window without parallax.
extern const char kNoParallaxNote[];

// LR depth maps of the initialisation up-sampled to HR (Sec.
// optInitialization): bicubic on inverse depth, so that holes and edges behave.
std::vector<cv::Mat> UpsampleInitialDepth(const std::vector<cv::Mat>& depth_lr, int scale);

class Estimator {
 public:
  explicit Estimator(const EstimatorOptions& options);
  // Throws InputError on inconsistent input, InitializationError when the
  // frames cannot be initialised. A window in which no pair of frames has
  // parallax (NoParallaxError of the initialiser) is estimated by
  // RunRotationOnly from the orientations of EstimateRotationOnlyMotion.
  EstimatorResult Run(const EstimatorInput& input, const ProgressCallback& progress = nullptr);

  // Algorithm 1 from a given structure (tests: ground-truth depth and poses;
  // the node: the previous window's poses). depth_hr/T_world_cam must have one
  // entry per frame; the latent images start as bicubic up-samplings.
  EstimatorResult RunFromStructure(const EstimatorInput& input, const std::vector<cv::Mat>& depth_hr,
                                   const std::vector<SE3>& T_world_cam,
                                   const ProgressCallback& progress = nullptr);

  // A window whose motion is a rotation (no pair has parallax;
  // docs/file_formats.md#no-parallax): with depth at infinity the warps are
  // the homographies of the orientations of T_world_cam, and the capture
  // operator follows the rotation path. Every camera takes the translation of
  // T_world_cam[0]; only the images are estimated (eq:imgUpdate); depth
  // comes out NaN. The result keeps T_world_cam's world.
  EstimatorResult RunRotationOnly(const EstimatorInput& input, const std::vector<SE3>& T_world_cam,
                                  const ProgressCallback& progress = nullptr);

  // While *flag is true, runs throw EstimationCancelled at the next frame or
  // stage boundary. The flag must outlive the runs; nullptr: never cancelled.
  void SetCancelFlag(const std::atomic<bool>* flag) { cancel_ = flag; }
  const EstimatorOptions& options() const { return options_; }

 private:
  using InnerRun = std::function<EstimatorResult(Estimator*, const EstimatorInput&)>;
  // `run` on an estimator without gain compensation, given the input divided
  // by its frame gains; the latent images multiplied back.
  EstimatorResult RunGainCompensated(const EstimatorInput& input, const InnerRun& run) const;
  EstimatorResult RunInputDenoised(const EstimatorInput& input, const InnerRun& run) const;
  void ThrowIfCancelled() const {
    if (cancel_ != nullptr && cancel_->load()) throw EstimationCancelled();
  }

  EstimatorOptions options_;
  const std::atomic<bool>* cancel_ = nullptr;
};

}  // namespace deblur_sr_mvs
