// The capture operator Psi_t of eq:blurOperator as a sparse matrix.
//
// (Psi_t I)(x) = box-downsample( (1/M) sum_m I( W^{tau_m -> src}(x) ) ):
// M virtual cameras at tau_m = t_o + ((m - 1/2)/M)(t_c - t_o), m = 1..M (the
// midpoint of each slice of the exposure; eq:blurOperator has m/M), on the pose
// path (PoseAtTime: eq:interpolatingP's geodesic, or the curve through the
// frames on both sides that reduces to it at constant velocity), each seeing
// depth D_tau_m reprojected from D_t;
// their pixels are warped into the camera `src` whose latent image is sampled
// (src = t for the self-consistency term eq:IPterm, a neighbour s for the
// matching term eq:matchingTerm), read bilinearly and box-averaged by `scale`.
// With depth and poses fixed it is linear in I: a (LR pixels x HR pixels)
// matrix whose rows hold the merged bilinear taps; its transpose is the exact
// adjoint. Multi-channel images share the operator (interleaved channels).
#pragma once

#include <cstddef>
#include <optional>
#include <vector>

#include <Eigen/SparseCore>
#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/se3.h"
#include "deblur_sr_mvs/core/imaging/row_run_matrix.h"

namespace deblur_sr_mvs {

struct CaptureOperatorOptions {
  // M, the number of virtual cameras over the exposure (paper: 50); with
  // adaptive_samples, the most a frame gets.
  int samples = 50;
  // Adaptive M: each frame gets about `samples_per_pixel` virtual cameras per
  // HR pixel of its blur (the largest image motion over a row's exposure,
  // see BlurLengthHr), at least `min_samples` and at most `samples`; a
  // rolling shutter's reprojected depths, which span the exposure plus the
  // readout, follow the motion over that span (DepthCameraCount). Sampling
  // the exposure finer than the bilinear taps resolve adds work, not
  // accuracy.
  bool adaptive_samples = false;
  double samples_per_pixel = 1.0;
  int min_samples = 4;
  // Integer super-resolution factor: HR = scale x LR (box filter).
  int scale = 2;
  // Depth of each virtual camera by z-buffered reprojection of D_t (paper,
  // Sec. 3). false approximates D_tau(x) by D_t(x): faster, wrong at
  // depth edges.
  bool reproject_depth = true;
  // OpenMP threads for building and applying; 0 uses the OpenMP default.
  int num_threads = 0;
  // Keep a transposed copy for a parallel Psi^T (twice the memory). Without
  // it Psi^T scatters through Psi on one thread, as fast as the copy on one
  // thread: callers that run one operator per thread leave it off.
  bool transposed_copy = true;
  // Throws InputError with a one-line reason when a value is unusable.
  void Check() const;
};

// What fixes Psi_t: D_t, P_t, P_s, the shutter interval (paper Sec. 3).
struct CaptureGeometry {
  PinholeCamera camera_hr;       // intrinsics of the latent (HR) images
  cv::Mat depth_hr;              // D_t: CV_32FC1, HR size, metres; 0 or NaN unknown
  SE3 T_world_cam;               // P_t: pose at the shutter close time t = t_c
  SE3 T_world_neighbour;         // P_s: pose of the neighbouring frame for eq:interpolatingP
  double stamp = 0.0;            // t (= t_c), seconds
  double neighbour_stamp = 0.0;  // s: the previous frame's stamp; the first frame of
                                 // a sequence passes the NEXT frame (s > t), and the
                                 // same formula then extrapolates backwards from P_t
                                 // at constant velocity.
  // A second neighbouring frame's pose and stamp (s2, distinct from s and t):
  // the path is then the quadratic in se(3) through P_s, P_t and P_s2
  // (PoseOnPolynomialPath), which follows an accelerating camera and is the
  // geodesic of eq:interpolatingP when the three lie on one constant-velocity
  // path. Empty: the geodesic through P_s and P_t. SetBlurPath fills both.
  std::optional<SE3> T_world_second_neighbour;
  double second_neighbour_stamp = 0.0;
  // A third (s3, distinct from the others; only with a second): the cubic
  // through the four poses, which follows a changing acceleration too.
  std::optional<SE3> T_world_third_neighbour;
  double third_neighbour_stamp = 0.0;
  double exposure = 0.0;         // t_c - t_o, seconds, 0 < exposure
  // Rolling shutter (docs/file_formats.md#rolling-shutter): LR row y of H is
  // exposed over [t_o + y r / H, t_c + y r / H], r = readout_time (0: a
  // global shutter); every HR row of LR row y shares its window. The
  // latent image stays the global-shutter image at P_t, so the operator also
  // models (and the image update undoes) the rolling-shutter distortion.
  double readout_time = 0.0;
  // The camera whose latent image the operator samples; empty = P_t itself.
  std::optional<SE3> T_world_source;
};

// True when `a` and `b` fix the same operator bit for bit: the same camera,
// D_t of the same size and bytes (NaN payloads included), the same poses
// (P_t, the neighbours, P_source or their absence), stamps, exposure and readout.
// Building from either gives the same operator (the builder is deterministic).
bool SameCaptureGeometry(const CaptureGeometry& a, const CaptureGeometry& b);
// True when the options give the same operator from the same geometry
// (num_threads and transposed_copy do not change its matrix).
bool SameOperatorModel(const CaptureOperatorOptions& a, const CaptureOperatorOptions& b);

// at = a^T for compressed row-major matrices, on `threads` threads (0: all).
void TransposeSparse(const SparseMatrixRM& a, SparseMatrixRM* at, int threads);
// out = a * in for an interleaved C-channel float image `in` with one pixel per
// column of `a`; `out` becomes a (rows x 1) C-channel image (reshape as needed).
void MultiplySparse(const SparseMatrixRM& a, const cv::Mat& in, cv::Mat* out, int threads);
// The same over row runs (the products of CaptureOperator::Apply).
void MultiplySparse(const RowRunMatrix& a, const cv::Mat& in, cv::Mat* out, int threads);

// The pose at time `tau` on the frame's blur path (the curved path through
// the neighbours of `geometry`, or eq:interpolatingP's geodesic): the one
// place every user of the path (the operator, its blur length, the structure
// update's derivative, the initialiser) takes it from. Also extrapolates: the
// first frame's opening lies before its neighbours, rolling-shutter rows close
// after the stamp.
SE3 PoseAtTime(const CaptureGeometry& geometry, double tau);

// The frames, besides t, whose poses fix frame t's blur path in a sequence of
// `num_frames` >= 2 frames, the neighbour P_s first. Frame t's exposure lies
// between t-1 and t, so with 4 or more frames an interior frame's path is the
// cubic through t-2, t-1, t and t+1 (t = 1: 0, 2 and 3), interpolating over
// the exposure and past t (a rolling shutter's rows) up to t+1; with 3 frames
// the quadratic through all three. At either end the quadratic through the
// next two frames inwards: the first frame's extrapolated backwards over its
// exposure, the last frame's forwards over a rolling shutter's readout (a
// cubic extrapolated there weighs the poses' errors more: the last frame's
// cubic lost depth on the rolling-shutter benchmark). With 2 frames the
// geodesic of eq:interpolatingP through both.
// Model agreement from the ground truth on noise-free hand-held clips
// (BENCHMARKS.md "A cubic blur path for the interior frames"): the
// quadratic through t-1, t and t+1 reproduced the interior frames' blur to
// 39-55 dB, the cubic 0.3-2.2 dB better on average (-2.5 to +5.8 dB per
// frame, the losses mostly at frame 1); the first frame's quadratic to
// 33-46 dB where the geodesic extrapolated from frame 1 gave 27-32 dB on
// most seeds (not every shake: BENCHMARKS.md "The first frame's blur on
// the curve"). The first frame's curve multiplies the errors of the poses
// it extrapolates from (Lagrange weights 2.52 / -2.24 / 0.72 at an exposure
// of 0.8 frame intervals, against 1.8 / -0.8): it pays only with
// shutter-close poses that follow the acceleration too
// (MidExposureToShutterClose).
std::vector<int> BlurPathFrames(int t, int num_frames);
// Sets the path of `geometry` (P_t, t and the neighbours) to frame t's among
// the poses (at shutter close) and stamps of a sequence (BlurPathFrames).
void SetBlurPath(const std::vector<SE3>& T_world_cam, const std::vector<double>& stamps, int t,
                 CaptureGeometry* geometry);
// Moves the path of `geometry` rigidly and in time onto the pose
// `T_world_target` at `target_stamp`: every pose of the path becomes
// T_target P_t^-1 P, every stamp shifts by target_stamp - t (the same motion
// in the camera frame, as seen from the target).
void MoveBlurPath(const SE3& T_world_target, double target_stamp, CaptureGeometry* geometry);

// Poses T_world_tau_m of the M virtual cameras over the exposure of the rows
// that open `row_delay` seconds after row 0 (y r / H for LR row y).
std::vector<SE3> VirtualCameraPoses(const CaptureGeometry& geometry, int samples, double row_delay = 0.0);
// The delay of LR row `lr_row` of `lr_rows` (y r / H; 0 for a global shutter).
double RowDelay(const CaptureGeometry& geometry, int lr_row, int lr_rows);

// An up-sampled blurred frame re-centred on the shutter close: out(x) =
// image(x_mid), x_mid the projection of the point that HR pixel x of the
// latent image shows (inverse depth rho(x) at P_t, geometry.camera_hr) into
// the camera at mid-exposure on the frame's blur path (PoseAtTime at t - e/2,
// plus x's LR row's delay with a rolling shutter; `scale` HR rows per LR
// row), bilinear. A blurred frame is centred on its mid-exposure camera,
// while the latent image, D_t and the pairs' warps are the close camera's:
// at depth edges the plain input shows its content half a blur away from
// where D_t puts it (EstimatorOptions::recentred_depth_pass). `valid`
// (CV_8UC1, 255 / 0): rho(x) usable and x_mid in front of the camera and at
// least one pixel inside the image. Where rho(x) is unusable or x_mid behind
// the camera out(x) = image(x); outside the image the border is replicated.
void RecentreOnShutterClose(const CaptureGeometry& geometry, int scale, const cv::Mat& inverse_depth,
                            const cv::Mat& image, cv::Mat* out, cv::Mat* valid);

// The blur length of the frame: the largest displacement, in HR pixels, of an
// image point between the opening and the closing of its row's exposure, over
// a grid of points (every 8th HR pixel) at their own depth D_t (unknown depth
// does not move, as in the operator). Independent of the source camera.
double BlurLengthHr(const CaptureGeometry& geometry, int scale);
// How much the blurs of frames a and b differ: the mean, over a grid of
// frame a's points (every 8th HR pixel) at their depth D_a that b also sees
// (at its pose P_b), of the length of the difference between the point's
// blur vectors in a and in b (its image motion from the opening to the
// closing of its row's exposure), in HR pixels. 0 when both frames move
// alike (a constant-velocity path); NaN when no point qualifies (no known
// depth, or b sees none of them). The two geometries must share the HR
// camera.
double BlurDifferenceHr(const CaptureGeometry& a, const CaptureGeometry& b, int scale);
// M for the frame of `geometry` under `options` (options.samples unless
// options.adaptive_samples); the same for every source camera.
int CaptureSamples(const CaptureGeometry& geometry, const CaptureOperatorOptions& options);
// K, the number of depths D_tau reprojected from D_t for the frame of
// `geometry`: M for a global shutter (one per virtual camera); for a rolling
// shutter, whose M virtual cameras per LR row each read the nearest of K
// depths spread over the exposure plus the readout, about twice
// samples_per_pixel per HR pixel of the motion over that span
// (options.samples unless adaptive), clamped as M is.
int DepthCameraCount(const CaptureGeometry& geometry, const CaptureOperatorOptions& options);

// The depths D_tau the virtual cameras of one frame see, reprojected from D_t
// (paper, Sec. 3). They depend on D_t, P_t, P_neighbour, the stamps, the
// exposure and the shutter, not on the source camera: computed once, they
// serve the operators of the frame for every source (the builder then skips
// its own reprojections; the operator is bit-identical).
class VirtualDepths {
 public:
  VirtualDepths() = default;
  // Reprojects geometry.depth_hr into the frame's virtual cameras with
  // options.num_threads threads (geometry.T_world_source is ignored). Keeps a
  // reference to geometry.depth_hr: Build accepts these depths only for that
  // same depth buffer (not modified in place since) and the same poses.
  void Compute(const CaptureGeometry& geometry, const CaptureOperatorOptions& options);
  // M of the frame (CaptureSamples); 0 before Compute.
  int samples() const { return samples_; }
  // Wall time of the last Compute.
  double compute_ms() const { return compute_ms_; }
  size_t Bytes() const;

 private:
  friend class CaptureOperatorBuilder;
  int samples_ = 0;
  int scale_ = 0;
  bool reprojected_ = false;
  double compute_ms_ = 0.0;
  cv::Mat depth_t_;              // D_t (shallow: identifies the buffer)
  std::vector<SE3> T_depth_t_;   // the depth cameras, T_tau_t
  std::vector<cv::Mat> depths_;  // D_tau, one per depth camera
};

class CaptureOperator {
 public:
  CaptureOperator() = default;

  // LR size (rows of the matrix) and HR size (columns).
  cv::Size lr_size() const { return lr_size_; }
  cv::Size hr_size() const { return hr_size_; }
  // Psi as runs of consecutive columns (RowRunMatrix: about half the bytes
  // of CSR); matrix().ToCsr() gives the CSR form.
  const RowRunMatrix& matrix() const { return forward_; }
  // Fraction of each LR pixel's M * scale^2 samples that landed inside the
  // source image in front of the camera (the rest were clamped to the
  // border); 1 everywhere for an interior pixel.
  const std::vector<float>& coverage() const { return coverage_; }

  // lr = Psi hr. `hr` is CV_32FC(C) of hr_size(); `lr` is (re)allocated as
  // CV_32FC(C) of lr_size() only when needed.
  void Apply(const cv::Mat& hr, cv::Mat* lr) const;
  // hr = Psi^T lr, the exact adjoint of Apply.
  void ApplyAdjoint(const cv::Mat& lr, cv::Mat* hr) const;

 private:
  friend class CaptureOperatorBuilder;
  cv::Size lr_size_;
  cv::Size hr_size_;
  int num_threads_ = 0;
  RowRunMatrix forward_;
  SparseMatrixRM adjoint_;  // forward_ transposed, CSR (optional): a parallel gather
  std::vector<float> coverage_;
};

// Builds capture operators; keeps its scratch buffers between builds so a
// sequence of frames allocates once.
class CaptureOperatorBuilder {
 public:
  explicit CaptureOperatorBuilder(const CaptureOperatorOptions& options);
  // Throws InputError on inconsistent geometry (sizes, stamps, exposure).
  void Build(const CaptureGeometry& geometry, CaptureOperator* op);
  // The same with the frame's virtual depths computed beforehand (shared by
  // the operators of every source of the frame); throws InputError when they
  // were computed for another D_t, other poses or other options.
  void Build(const CaptureGeometry& geometry, const VirtualDepths& shared, CaptureOperator* op);
  const CaptureOperatorOptions& options() const { return options_; }

  // Wall time of the stages of the last Build, for profiling and reports.
  struct Timings {
    double reprojection_ms = 0.0;  // D_tau_m for every virtual camera (0 when shared)
    double assembly_ms = 0.0;      // warps, bilinear taps, merged rows
    double adjoint_ms = 0.0;       // the transposed copy
  };
  const Timings& last_timings() const { return timings_; }

 private:
  // Plans the warps and assembles the rows from the frame's virtual depths.
  void Assemble(const CaptureGeometry& geometry, const VirtualDepths& depths, CaptureOperator* op);

  Timings timings_;
  CaptureOperatorOptions options_;
  VirtualDepths own_depths_;                     // D_tau_m when not shared
  std::vector<RowRunMatrix::RowBlock> blocks_;   // per-thread row runs
};

// Convenience: one operator with a temporary builder.
CaptureOperator BuildCaptureOperator(const CaptureGeometry& geometry, const CaptureOperatorOptions& options);

}  // namespace deblur_sr_mvs
