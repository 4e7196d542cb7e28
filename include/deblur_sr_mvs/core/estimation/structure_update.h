// The structure update of Sec. optDepthAndCamera: with the latent images
// fixed, the matching terms are linearised in inverse depth and both poses
// (eq:taylorExpansion, eq:updateVariables) and solved by IRLS; depth carries
// the edge-weighted TV of eq:regularizingTerm.
#pragma once

#include <memory>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/frame_types.h"
#include "deblur_sr_mvs/core/geometry/se3.h"
#include "deblur_sr_mvs/core/geometry/visibility.h"
#include "deblur_sr_mvs/core/imaging/capture_operator.h"

namespace deblur_sr_mvs {

// The preconditioner of the depth update's CG (StructureUpdateOptions).
enum class DepthPreconditioner {
  kNone,    // plain CG
  kJacobi,  // 1 / diag(N)
  // One symmetric Gauss-Seidel sweep on diag(N) + the off-diagonal depth TV
  // stencil (LaplacianGaussSeidelPreconditioner, as the image update's
  // ImagePreconditioner::kTvGaussSeidel): plain and Jacobi CG move the
  // solution one pixel per step through the TV term, which is all that
  // reaches the border pixels that few pairs see; the sweeps carry it across
  // the image in one application.
  kTvGaussSeidel,
};

struct StructureUpdateOptions {
  // Weight of the depth TV. The paper's 8 - 10 are in its own (unstated)
  // units of inverse depth and intensity; here the TV acts on inverse depth
  // expressed as parallax in HR pixels per mean inter-frame baseline, with
  // intensities in [0, 1], so the weight does not depend on the monocular
  // scale or the resolution. 0.1 was chosen on the synthetic Dolls and
  // Reindeer sequences (depth rel. error 0.0106 / 0.0285 against 0.0142 /
  // 0.0319 with 1.0).
  double lambda_d = 0.1;
  EdgeWeightOptions edge_weight;  // g_t
  int depth_irls_iterations = 3;  // re-linearisations (warps) per update
  // CG per reweighted system: at most
  // depth_cg_iterations steps, fewer once the residual is below
  // depth_cg_tolerance x the right-hand side's norm (0: always all steps).
  int depth_cg_iterations = 15;
  double depth_cg_tolerance = 0.05;
  // The depth CG's preconditioner. kNone: with Jacobi, 15 steps reach a
  // different (not better) step; on the exact-prior test sequence the depth
  // in metres came out 0.0102 rel. error against 0.0090 without it. The
  // estimator's re-centred passes, which end the estimation, solve further
  // with their own (EstimatorOptions::recentred_depth_preconditioner).
  DepthPreconditioner depth_preconditioner = DepthPreconditioner::kNone;
  int pose_iterations = 6;         // Gauss-Newton steps of the joint pose update
  double residual_epsilon = 1e-3;  // L1 smoothing (intensity in [0, 1])
  double tv_epsilon = 0.05;        // TV smoothing, parallax px
  double depth_damping = 1e-3;     // Levenberg damping relative to the data diagonal
  double pose_damping = 1e-4;      // likewise for the pose normal equations
  // HR pairs of the pose update use every stride-th pixel of every
  // stride-th row (shifted row to row): six unknowns per frame need far
  // fewer than every pixel, and the update costs 1/stride^2.
  int pose_pixel_stride = 2;
  // Joint depth + pose step (UpdateDepthAndPoses): the estimator replaces the
  // per-frame depth updates by one Gauss-Newton/IRLS step in which every
  // frame's inverse depth and the free poses move together, so that depth
  // cannot absorb a pose error; the pose update follows as before. On: on 8
  // sequences (lateral, arc, forward, hand-held; Dolls, Aloe) mean depth
  // 0.891 and ATE 0.800 of the baseline's against 0.904 and 0.934 with the
  // per-frame depth updates (depth 0.0004 worse on lateral / Aloe), at
  // +9 % to +14 % CPU (one or two threads) and a peak of 1.01 - 1.24 GiB
  // (against 0.88 - 1.08) on the 10-frame 640x480 speed sequences
  // (BENCHMARKS.md "Joint depth + pose step (Schur)"). false: the
  // per-frame depth updates.
  bool joint_depth_pose_step = true;
  // CG steps per reweighted joint system (its tolerance is
  // depth_cg_tolerance).
  int joint_cg_iterations = 30;
  // Reweightings (re-linearisations) of the joint step per structure update
  // (the per-frame depth updates take depth_irls_iterations). 2 was measured
  // on the 8 sequences of joint_pose_damping against 3: the same mean depth
  // and ATE (0.890 / 0.853 of the baseline's against 0.891 / 0.852), 16 %
  // less CPU.
  int joint_irls_iterations = 2;
  // Levenberg-Marquardt damping of the pose block inside the joint step,
  // relative to the pose block's own diagonal (the pose update's matching
  // terms, before the depth is eliminated). The depth can trade for a
  // rotation (bas-relief): that direction of the reduced camera system is
  // nearly singular, and the damping keeps the step from drifting along it.
  // 0.01 was measured on 8 sequences (Dolls, Aloe x lateral, arc, forward,
  // hand-held): with 1e-4 the lateral and arc Aloe windows drift (ATE 4.1x
  // the baseline's); 0.01 keeps the depth gain elsewhere; 0.1 and more lose it.
  double joint_pose_damping = 0.01;
  // The joint step matches every pair within the pose update's radius
  // (EstimatorOptions::pose_neighbour_radius) instead of N(t): longer
  // baselines tie each pose to more frames, in depth and pose alike. Off:
  // measured, it holds the lateral poses but loses depth on the arc and
  // hand-held paths and costs a fifth more.
  bool joint_step_pose_pairs = false;
  // Coarse-to-fine (issue 14): before the joint step at full resolution,
  // UpdateDepthAndPoses runs the same step on the images, masks, edge
  // weights and inverse depths box-downsampled by 2, 4, ... (this many
  // levels, coarsest first; a level whose size does not divide is skipped)
  // and adds each level's inverse-depth increments, bilinearly up-sampled,
  // to the finer maps; the poses move at every level. A coarse grid moves a
  // depth edge or a smooth region by more full-resolution pixels per step
  // (a wider basin, faster TV propagation). HR pairs only: frames with the
  // blurred pairs or the self-consistency term skip the coarse levels.
  // It also speeds the poses: a bas-relief trade of the poses for a bend of
  // the depth is nearly singular in the pose block, so with the damping
  // (joint_pose_damping) each full-resolution reweighting moves the poses
  // only part of the way, and both modes' ATE still falls from one
  // iteration to the next (hand-held / Reindeer, seed 2: joint 3.94, 3.77,
  // 3.50, 3.23 mm after 0-3 iterations, 2.72 after 6). The coarse level
  // adds two cheap reweightings along that low-frequency trade.
  // 1 (default) against 0 on the 96 benchmark sequences of seeds 0-3, per
  // path: ATE 0.90-0.98x on lateral, arc, hand-held and gain-jitter paths
  // (forward 1.01x, rolling 1.02x), full-frame depth 0.91-0.96x on all but
  // forward (1.00x), +0.02 to +0.11 dB on all six, about 3 % more time;
  // the centre-crop depth within 0.5 % of before except on forward (1.04x)
  // and rolling (1.02x) paths. The baseline's ATE falls too (0.97x) and
  // its crop depth rises (1.04x) (BENCHMARKS.md "One coarse level of the
  // joint step by default").
  // Skipped where a pose prior enters the step: with an exact prior on 8
  // sequences the level raised the depth error in metres on 6 (up to 1.06x)
  // while the prior already held the poses. 0: off.
  int joint_coarse_levels = 1;
  // Blur as motion evidence (EstimatorOptions::blur_pose_evidence): the
  // self-consistency term's Jacobian in the poses (LinearizeBlurInPoses)
  // from at most this many of Psi_t's virtual cameras, evenly spread over
  // the exposure, ...
  int blur_pose_samples = 8;
  // ... on every blur_pose_stride-th LR pixel of every blur_pose_stride-th
  // LR row (shifted row to row; the term's weight is multiplied by
  // stride^2, so that it stands for every pixel), ...
  int blur_pose_stride = 1;
  // ... with the weight blur_pose_weight x lambda_s (1: the weight of
  // eq:IPterm in the energy).
  double blur_pose_weight = 1.0;
  // The blur evidence's sharp image: false, I_t itself (the self-consistency
  // term, LinearizeBlurInPoses, weight lambda_s); true, the latent images of
  // N(t) warped into t (the blurred matching pairs of eq:matchingTerm,
  // LinearizeBlurredPairInPoses, weight 1 each): I_t was fitted to B_t
  // through the current blur, which then holds the poses where they were.
  bool blur_pose_from_pairs = false;
  // A pair whose two frames both have held poses (the `num_fixed` leading
  // frames: the frames a stream's window shares with the previous one)
  // enters only the held poses' rows and columns of the pose systems, which
  // the held poses then zero. true: its pose terms are not formed (in the
  // joint step its pose Jacobians and depth-pose couplings, in UpdatePoses
  // its normal equations; the estimator does not match it in the pose
  // update), unless a pose prior needs its residuals. Exact: the outputs are
  // bit for bit those of false, which only the test that checks it uses
  // (test/core/estimation/held_pose_work_test.cc).
  bool skip_held_pose_work = true;
  int num_threads = 0;
  void Check() const;
};

// Matching data of one ordered pair (t <- s): the observation of frame t is
// predicted from the latent image of s warped into t (eq:matchingTerm).
struct PairMatching {
  int t = 0;
  int s = 0;
  const CaptureOperator* blur = nullptr;  // Psi_t (self); nullptr: no capture
                                          // operator (baseline: HR residuals)
  const cv::Mat* observation = nullptr;   // B_t (LR) or, without blur, the HR image
  cv::Mat mask;                           // Omega_ts on the observation grid (CV_8UC1)
  const cv::Mat* source = nullptr;        // image of s warped into t; nullptr: latents[s]
                                          // (HR pairs: another image pair, e.g. the inputs)
  // Scales the pair's IRLS weights in the depth update and the joint depth +
  // pose step (UpdateDepth, UpdateDepthAndPoses; 0: as if the pair were
  // absent). UpdatePoses takes every pair at weight 1.
  float weight = 1.0f;
};

// Residual images of the linearisation for one pair at the current structure:
// warped latent image I_s(W^{t->s}) and its derivatives.
struct WarpLinearization {
  cv::Mat warped;           // HR, C channels
  cv::Mat d_inverse_depth;  // HR, C channels: d warped / d rho_t
  cv::Mat valid;            // HR CV_8UC1: warp inside I_s and in front
};

// I_s(W^{t->s}(y)) and its derivative w.r.t. the inverse depth of y, for every
// HR pixel y of t; `pose_jacobians` (optional, 6 images of C channels) gets
// d/d eps_t of the warped image for P_t = exp(eps_t) P_t0 (d/d eps_s is minus it).
WarpLinearization LinearizeWarp(const PinholeCamera& camera_hr, const cv::Mat& inverse_depth_t,
                                const SE3& T_world_t, const SE3& T_world_s, const cv::Mat& latent_s,
                                std::vector<cv::Mat>* pose_jacobians);

// The self-consistency term lambda_s |B_t - Psi_t(D_t) I_t| (eq:IPterm)
// linearised in the inverse depth of t: the virtual cameras of Psi_t sample
// I_t where the depth sends them, so Psi_t(rho + d) I_t ~= Psi_t I_t +
// Box(h .* d) with h = mean_m grad I_t(W^{tau_m->t}) . dW/drho (D_tau ~ D_t).
struct SelfConsistencyLinearization {
  const cv::Mat* observation = nullptr;  // B_t (LR)
  cv::Mat predicted;                     // Psi_t I_t at the current depth (LR)
  cv::Mat derivative;                    // h (HR, C channels)
  double weight = 0.0;                   // lambda_s
  int scale = 1;
};
// h for the geometry of Psi_t (its depth is ignored; `inverse_depth` is used)
// from at most `max_samples` of its virtual cameras (per LR row of `scale`
// HR rows with a rolling shutter).
cv::Mat BlurDerivativeWrtInverseDepth(const CaptureGeometry& geometry, int samples, int scale,
                                      const cv::Mat& inverse_depth, const cv::Mat& latent, int max_samples);

// One IRLS depth update of frame t from its pairs (all with pair.t == t);
// `latents` are the latent images of every frame (only the pairs' s are read).
// Updates inverse_depth in place. `parallax_scale` = f_hr * mean baseline.
void UpdateDepth(const PinholeCamera& camera_hr, const std::vector<SE3>& T_world_cam,
                 const std::vector<cv::Mat>& latents, const std::vector<PairMatching>& pairs,
                 const SelfConsistencyLinearization* self, const cv::Mat& edge_weight, double parallax_scale,
                 const StructureUpdateOptions& options, cv::Mat* inverse_depth);

// Blur as motion evidence: the self-consistency term lambda_s |B_t - Psi_t
// I_t| (eq:IPterm) linearised in the poses that fix Psi_t's blur path
// (eq:interpolatingP: P_t and the frames of BlurPathFrames), so that the
// length and direction of the blur in B_t are evidence about the motion.
// With r(eps) = r0 - J eps, r0 = B_t - Psi_t I_t, J = d (Psi_t I_t) / d eps
// for P_f = Exp(eps_f) P_f0 (f in `frames`), and the L1 IRLS weights W of
// r0 (held for the pose update's Gauss-Newton steps): hessian = weight J^T
// W J, gradient = weight J^T W r0.
struct BlurPoseTerm {
  std::vector<int> frames;   // t first, then its blur path's frames
  Eigen::MatrixXd hessian;   // 6 frames.size() square
  Eigen::VectorXd gradient;  // 6 frames.size()
};

// J = d (Psi_t I_t) / d eps (LR, C x 6F channels: channel c of the
// observation, frame k of the geometry's path (P_t, P_neighbour, then
// P_second_neighbour and P_third_neighbour if set), axis j at channel
// (c * F + k) * 6 + j), for the self-consistency geometry of frame t (its
// T_world_source must be empty: the operator samples I_t). The virtual cameras of Psi_t see
// I_t(W^{tau_m->t}(x)) at depth D_t (D_tau ~ D_t, as in
// BlurDerivativeWrtInverseDepth, `inverse_depth` standing for the
// geometry's depth); the pose derivative of each virtual camera relative to
// P_t is taken by central differences of the path (PoseAtTime) over the 6
// axes of each pose, fitted by a cubic in tau - t (the path is one, through
// P_t at t: eq:interpolatingP, PoseOnPolynomialPath), and chained
// with the image gradient at the warp. At most `max_samples` of the
// `samples` virtual cameras; only the LR pixels of `stride` (see
// StructureUpdateOptions::blur_pose_stride), the others are zero.
cv::Mat BlurPoseJacobian(const CaptureGeometry& geometry, int samples, int scale, const cv::Mat& inverse_depth,
                         const cv::Mat& latent, int max_samples, int stride);

// The term of frame t from J (BlurPoseJacobian), r0 = observation -
// predicted (LR) and `weight` (lambda_s; multiplied by stride^2); `frames`
// are the frame indices of the geometry's path, t first.
BlurPoseTerm LinearizeBlurInPoses(const CaptureGeometry& geometry, const std::vector<int>& frames, int samples,
                                  int scale, const cv::Mat& inverse_depth, const cv::Mat& latent,
                                  const cv::Mat& observation, const cv::Mat& predicted, double weight,
                                  const StructureUpdateOptions& options);

// The blurred matching pair (t <- s) of eq:matchingTerm, B_t against Psi_t
// applied to I_s warped into t (W^{t->s} at `inverse_depth` of t), linearised
// in the poses of Psi_t's blur path (BlurPoseJacobian of the warped image)
// and of the warp (LinearizeWarp's pose Jacobians mapped by Psi_t, for P_t
// and P_s): the blur evidence from a sharp image that was not fitted to
// B_t. The mask is the warp's validity only (no occlusion set Omega_ts).
// `psi_t` is Psi_t sampling frame t (the geometry's operator);
// `frames` as in LinearizeBlurInPoses, the term's frames are them and s.
BlurPoseTerm LinearizeBlurredPairInPoses(const CaptureGeometry& geometry, const std::vector<int>& frames,
                                         int s, int samples, int scale, const cv::Mat& inverse_depth,
                                         const SE3& T_world_s, const cv::Mat& latent_s,
                                         const CaptureOperator& psi_t, const cv::Mat& observation, double weight,
                                         const StructureUpdateOptions& options);

// A pose prior (EstimatorInput::T_prior_cam) in the window's world, as
// terms of the structure update: per frame the prior's camera centre and
// orientation carried into the world by the similarity that aligns the
// window to the prior (AlignToPrior), Huber-weighted. The photometric terms
// do not see the monocular scale, nor, well, the bas-relief trade of a
// rotation against the inverse depths; the prior is the metric evidence
// for both (docs/file_formats.md#monocular-scale).
// Feature tracks as pose evidence (EstimatorOptions::track_pose_weight):
// the reprojection errors of the initialiser's tracks, observed at
// mid-exposure, with every track's point eliminated, so that they constrain
// the poses alone and do not depend on the depth maps.
struct TrackPoseTerms {
  std::vector<FeatureTrack> tracks;
  PinholeCamera camera;  // the tracks' (LR input) camera
  // Per track and observation k (frame first_frame + k): the camera when
  // the observation was exposed (mid-exposure of its row) relative to the
  // frame's pose, T_world_seen = T_world_cam * T_cam_seen.
  std::vector<std::vector<SE3>> T_cam_seen;
  double sigma_px = 0.5;       // the tracks' noise, LR px
  double huber = 2.0;          // quadratic up to this many sigmas
  double weight = 0.0;         // in units of the photometric terms (as PosePriorTerms::weight); 0: off
  // The gate: the weight is multiplied by clamp((cost / min_cost - 1 -
  // gate_start) / gate_width, 0, 1), cost the tracks' cost at the current
  // poses, min_cost its least value over the poses (TrackCostMinimum);
  // min_cost 0: no gate.
  double min_cost = 0.0;
  double gate_start = 0.2;
  double gate_width = 0.5;
  bool any() const { return weight > 0.0 && !tracks.empty() && T_cam_seen.size() == tracks.size(); }
};

// Adds the tracks' terms at T_world_cam to a pose system H eps = g (as
// AddPosePriorNormalEquations: frame f >= num_fixed at block f - offset, in
// units of `photometric_scale`), each track's point re-triangulated at the
// poses (DLT, then Gauss-Newton) and eliminated by its Schur complement;
// frames below num_fixed still fix the points. Returns the tracks' cost at
// T_world_cam: the squared residuals (px^2), each capped at (huber
// sigma_px)^2. With hessian == nullptr only the cost.
double AddTrackNormalEquations(const TrackPoseTerms& terms, const std::vector<SE3>& T_world_cam,
                               int num_fixed, int offset, double photometric_scale, Eigen::MatrixXd* hessian,
                               Eigen::VectorXd* gradient);

// The least cost of the tracks over the poses of the frames >= num_fixed
// (>= 1), by Levenberg-Marquardt on the tracks alone from T_world_cam.
double TrackCostMinimum(const TrackPoseTerms& terms, std::vector<SE3> T_world_cam, int num_fixed);

struct PosePriorTerms {
  // Per frame: the prior's camera centre in the world; none: no prior term
  // (no prior pose, or one the alignment left out).
  std::vector<std::optional<Eigen::Vector3d>> centre_world;
  std::vector<Eigen::Matrix3d> R_world_cam;  // per frame: the prior's orientation in the world
  double position_sigma = 0.0;  // per axis, world units (> 0 where a centre is given)
  double rotation_sigma = 0.0;  // radians; 0: centres only
  double huber = 2.0;           // quadratic up to this many sigmas (as the initialiser's)
  // Multiplies the terms' weight (EstimatorOptions::pose_prior_weight).
  double weight = 1.0;
  bool any() const;             // some frame has a term
  // Feature tracks as pose evidence: not a prior, but like it a pose term
  // that the photometric pairs do not give.
  TrackPoseTerms tracks;
  bool any_term() const { return any() || tracks.any(); }  // some term, a track's included
};

// Adds the prior's Huber-reweighted normal equations at T_world_cam to a
// pose system H eps = g (eps = (rho, phi) per frame, P_f <- Exp(eps_f) P_f),
// frame f >= num_fixed at block f - offset, in units of the photometric
// terms: `photometric_scale` b (their mean absolute residual) times
// prior.weight times the prior's 0.5 |e / sigma|^2; with weight 1 the MAP
// weighting of an L1 (Laplace, scale b) data term of independent values
// against the prior's Gaussian.
void AddPosePriorNormalEquations(const PosePriorTerms& prior, const std::vector<SE3>& T_world_cam,
                                 int num_fixed, int offset, double photometric_scale, Eigen::MatrixXd* hessian,
                                 Eigen::VectorXd* gradient);

// Gauss-Newton/IRLS update of all poses but the first `num_fixed` (>= 1; frame
// 0 is the gauge) from all pairs, with depth fixed, and the pose prior's
// terms if given (with any()). Returns the applied tangent steps (6 per
// frame; zero for the fixed frames). `blur_terms` (optional): blur as motion
// evidence, linearised at the given poses; each Gauss-Newton step sees them
// at r0 - J (the steps taken so far).
std::vector<Vector6d> UpdatePoses(const PinholeCamera& camera_hr, const std::vector<cv::Mat>& inverse_depths,
                                  const std::vector<cv::Mat>& latents, const std::vector<PairMatching>& pairs,
                                  const StructureUpdateOptions& options, std::vector<SE3>* T_world_cam,
                                  int num_fixed = 1, const PosePriorTerms* prior = nullptr,
                                  const std::vector<BlurPoseTerm>* blur_terms = nullptr);

// The terms of one frame's depth update (as UpdateDepth takes them).
struct FrameDepthTerms {
  std::vector<PairMatching> pairs;                     // all with pair.t == this frame
  const SelfConsistencyLinearization* self = nullptr;  // optional
  cv::Mat edge_weight;                                 // g_t (empty: 1)
};

// A vector of the joint system: one inverse-depth increment image per frame
// and 6 tangent components per frame (zero for the held frames).
struct JointStep {
  std::vector<cv::Mat> inverse_depths;  // HR CV_32FC1 each
  Eigen::VectorXd poses;                // 6 x frames
};

// The reweighted normal equations of all frames' depth terms (the systems
// UpdateDepth solves one by one) linearised in the inverse depths and the
// poses together (eq:taylorExpansion, eq:updateVariables): for a pair
// (t <- s) with r = r0 - Psi(g .* d_t + A (eps_t - eps_s)) (A the pose
// Jacobians of LinearizeWarp),
//   [ N_dd  N_dp ] [d  ]   [G^T Psi^T W r0 - lambda_d c^2 L_v rho]
//   [ N_pd  N_pp ] [eps] = [A^T Psi^T W r0 (t), minus it (s)      ]
// with N_dd each frame's depth system (data, self term, TV, damping), N_dp
// = G^T Psi^T W Psi A and N_pp the pose update's blocks (plus its damping).
// The first `num_fixed` poses are held; with one held pose the scale is
// fixed by holding the length of the first free frame's baseline to the
// held frame (the pose update alone fixes it by holding the depth), unless
// a pose prior (`prior`, optional) has a centre on a free frame: its terms
// join N_pp and the rhs, and fix the scale.
class JointDepthPoseSystem {
 public:
  JointDepthPoseSystem(const PinholeCamera& camera_hr, const std::vector<SE3>& T_world_cam,
                       const std::vector<cv::Mat>& latents, const std::vector<FrameDepthTerms>& frames,
                       double parallax_scale, const StructureUpdateOptions& options, int num_fixed,
                       const PosePriorTerms* prior = nullptr);
  ~JointDepthPoseSystem();
  // Linearises and reweights every term at the given state (T_world_cam is
  // the vector given to the constructor, read at each call).
  void Linearize(const std::vector<cv::Mat>& inverse_depths);
  // The right-hand side at the linearisation point (gauge-projected).
  JointStep RightHandSide(const std::vector<cv::Mat>& inverse_depths);
  // out = N in (`in` must satisfy the gauge: see ProjectGauge).
  JointStep ApplyNormal(const JointStep& in);
  // Zeroes the held poses' components and, with one held pose, the scale
  // component of the first free pose.
  void ProjectGauge(Eigen::VectorXd* poses) const;
  // Solves N step = rhs by CG preconditioned with the Schur complement of
  // N's depth diagonal (see the definition).
  JointStep Solve(const JointStep& rhs);
  // Applies a step: rho += d per frame (ApplyStep of the depth update: rho
  // keeps at least a quarter of itself) and P_f = Exp(eps_f) P_f.
  void ApplyStep(const JointStep& step, std::vector<cv::Mat>* inverse_depths, std::vector<SE3>* T_world_cam);

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

// joint_irls_iterations joint steps (JointDepthPoseSystem) of all frames'
// depths and the poses but the first `num_fixed` (>= 1), with the pose
// prior's terms if given. `frames[t]` holds
// frame t's depth terms; latents as in UpdateDepth.
void UpdateDepthAndPoses(const PinholeCamera& camera_hr, const std::vector<cv::Mat>& latents,
                         const std::vector<FrameDepthTerms>& frames, double parallax_scale,
                         const StructureUpdateOptions& options, int num_fixed, std::vector<SE3>* T_world_cam,
                         std::vector<cv::Mat>* inverse_depths, const PosePriorTerms* prior = nullptr);

}  // namespace deblur_sr_mvs
