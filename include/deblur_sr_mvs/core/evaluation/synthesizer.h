// Synthetic blurred, low-resolution sequences with ground truth, rendered from
// a two-view Middlebury scene (paper Sec. "Synthetic datasets"; docs/tools.md,
// `synthesize_sequence`).
//
// World frame = the view1 camera's optical frame (x right, y down, z forward).
// Both views become coloured 3D points; a virtual camera moving along a path
// (constant-velocity SE(3) geodesics, a pure rotation, or a seeded hand-held
// shake) is rendered by forward splatting with a z-buffer, and a blurred frame
// is the mean of many sub-frame renders over the exposure (per LR row with a
// rolling shutter), box-downsampled by the SR scale (eq:blurOperator).
#pragma once

#include <array>
#include <cstdint>
#include <iosfwd>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/se3.h"
#include "deblur_sr_mvs/core/io/sequence_io.h"

namespace deblur_sr_mvs {

// ------------------------------------------------------------------- scene

// One calibrated RGB-D view of the scene.
struct SceneView {
  PinholeCamera camera;  // at the stored (third-size) resolution
  SE3 T_world_cam;       // camera -> world
  cv::Mat image;         // CV_8UC3, BGR as OpenCV reads it
  cv::Mat depth;         // CV_32FC1, metres along the optical axis, 0 = unknown
};

struct StereoScene {
  std::string folder;
  std::array<SceneView, 2> views;  // view1 (world frame), view5
  double focal_px = 0.0;           // 3740/3 for the third-size Middlebury images
  double baseline_m = 0.0;         // 0.160
  int dmin = 0;                    // full-size disparity offset (dmin.txt)
  // Over the known depths of both views (m).
  double min_depth = 0.0;
  double median_depth = 0.0;
  double max_depth = 0.0;
};

// Reads a Middlebury 2005/2006 third-size scene folder: view1.png, view5.png,
// disp1.png, disp5.png (8-bit, 0 = unknown) and dmin.txt (see
// data/middlebury/SOURCES.md for the calibration used). Throws InputError with
// one line naming the file and the problem.
StereoScene LoadMiddleburyScene(const std::string& folder);

// The same scene seen by cameras with `zoom` times the focal length and image
// size (images bicubic-resampled, depth nearest-resampled; depths, poses and
// baseline unchanged). Lets the synthesizer make larger frames (e.g. 640x480
// HR for speed benchmarks) from the third-size scenes; the texture is then
// softer than a real camera's. zoom must be in [1, 4].
StereoScene ZoomScene(const StereoScene& scene, double zoom);

// --------------------------------------------------------------- renderer

struct RenderOptions {
  // Points within this relative depth of a pixel's z-buffer value blend into
  // it (soft splatting of one surface); farther ones are occluded.
  double depth_tolerance = 0.015;
  // A splat enters the z-buffer only with at least this bilinear weight, so a
  // point most of a pixel away does not fatten its surface over the background.
  double min_splat_weight = 0.05;
  // Total splat weight from which a view is taken to cover a pixel. The
  // secondary view renders only the pixels the primary leaves below it.
  double coverage_weight = 0.3;
  // Fill pixels no view covers (disocclusions) from their background neighbours.
  bool fill_holes = true;
  // -1: both views (the nearer one primary); 0 or 1: only that view (tests).
  int only_view = -1;
  // With both views: 0 or 1 makes that view primary; -1 the view nearer to
  // the rendered camera (SceneRenderer::PrimaryView). The synthesizer fixes
  // it per frame, so that every sub-frame of an exposure and its ground
  // truth come from the same view.
  int primary_view = -1;
};

struct RenderResult {
  cv::Mat image;      // CV_32FC3, 0..255, BGR
  cv::Mat depth;      // CV_32FC1, metres along the optical axis (0 where unfilled)
  cv::Mat hole_mask;  // CV_8UC1, 255 where no view covered the pixel (before filling)
  int num_holes = 0;
  int num_secondary = 0;  // pixels taken from the secondary view
  double HoleFraction() const { return image.empty() ? 0.0 : static_cast<double>(num_holes) / image.total(); }
};

// Reusable buffers of one rendering thread (contents are internal), so that
// rendering many sub-frames allocates nothing per frame.
struct RenderWorkspace {
  std::vector<float> u, v, z;  // projections of one view's points
  struct Splat {
    int point;     // index into the view's points
    int x0, y0;    // top-left pixel of the 2x2 bilinear footprint
    bool inside;   // the whole footprint is in the image
    float ax, ay;  // bilinear fractions
  };
  std::vector<Splat> active;    // splats into pixels this view renders
  std::vector<uint8_t> useful;  // secondary: footprints worth splatting
  std::array<std::vector<float>, 2> zbuffer;
  std::array<std::vector<float>, 2> accum;  // per pixel: b, g, r, weight, weight*z
  std::vector<int> holes, next_holes, filled;
  std::vector<float> fill_values;  // b, g, r, z per filled pixel of one fill pass
};

class SceneRenderer {
 public:
  explicit SceneRenderer(const StereoScene& scene);

  // Renders the sharp image and depth seen by `camera` at pose T_world_cam by
  // forward splatting: per view a z-buffer over bilinear 2x2 footprints, then
  // colour and depth blended from the splats near the front surface.
  // Thread-safe (const) as long as each thread has its own workspace.
  void Render(const PinholeCamera& camera, const SE3& T_world_cam, const RenderOptions& options,
              RenderWorkspace* workspace, RenderResult* result) const;
  RenderResult Render(const PinholeCamera& camera, const SE3& T_world_cam,
                      const RenderOptions& options = RenderOptions()) const;

  // A renderer holding only the points that can reach `camera`'s image at a
  // pose on the straight-in-image path through the given poses (e.g. an
  // exposure's start, middle and end): it renders the same images there, faster.
  SceneRenderer CulledFor(const PinholeCamera& camera, const std::vector<SE3>& T_world_cams) const;

  int NumPoints(int view) const { return static_cast<int>(points_[view].x.size()); }
  // The view whose centre is nearer to a camera at T_world_cam (view 0 on
  // their bisector, to within 1e-9 of the baseline): it sees the most
  // similar surfaces, so it is primary and the other fills its holes.
  int PrimaryView(const SE3& T_world_cam) const;

 private:
  SceneRenderer() = default;
  // Structure of arrays so that the projection loop vectorises.
  struct Points {
    std::vector<float> x, y, z;  // world
    std::vector<float> b, g, r;
    void Reserve(std::size_t n);
    void Append(const Points& other, std::size_t i);
  };
  std::array<Points, 2> points_;
  std::array<Eigen::Vector3d, 2> view_centres_world_;
};

// ------------------------------------------------------------ camera paths

enum class CameraPathType { kLateral, kArc, kForward, kHandheld, kRotate };

std::string CameraPathName(CameraPathType type);
// "lateral", "arc", "forward", "handheld" or "rotate"; throws InputError otherwise.
CameraPathType ParseCameraPathType(const std::string& name);

// One low-frequency component of the hand-held path: amplitude * sin(2 pi
// cycles * u + phase), u = (t - t_mid) / duration.
struct PathSinusoid {
  double amplitude = 0.0;
  double cycles = 0.0;  // over the path's duration
  double phase = 0.0;   // rad
};

// The seeded shape of the hand-held path, in units that `speed` scales.
struct HandheldShape {
  double duration = 1.0;                                 // s, the rendered span of the path
  std::array<std::vector<PathSinusoid>, 3> translation;  // m per (m/s of speed), world x, y, z
  std::array<std::vector<PathSinusoid>, 3> rotation;     // rad per (m/s of speed), world axes
};

// Constant-velocity motion: T_world_cam(t) = Exp((t - t_mid) * speed * unit_twist)
// * T_world_mid, a one-parameter subgroup, so between any two frames the path is
// exactly the SE(3) geodesic of eq:interpolatingP. The twist is in the world
// frame (left-multiplied), ordered (rho, phi) as in se3.h. `rotate` is such a
// twist too (a rotation about the camera centre: rho = c x phi). `handheld` is
// not: T_world_cam(t) = (Exp(speed * rotation(t)), centre + speed * (t - t_mid)
// * unit_twist.rho + speed * translation(t)) with the sinusoids of `handheld`.
struct CameraPath {
  CameraPathType type = CameraPathType::kLateral;
  double t_mid = 0.0;  // time at which the camera is at T_world_mid
  SE3 T_world_mid;     // midpoint between view1 and view5, looking along +z
  Vector6d unit_twist = Vector6d::Zero();
  double speed = 0.0;  // multiplies unit_twist (m/s of the camera centre at t_mid)
  Eigen::Vector3d fixation_point = Eigen::Vector3d::Zero();  // arc only
  HandheldShape handheld;                                    // handheld only

  SE3 PoseAt(double t) const;
  Vector6d Twist() const { return speed * unit_twist; }  // per second
};

// The path through the midpoint of the two views at t_mid with speed 0;
// `arc_fixation_factor` places the arc's fixation point at that multiple of
// the median depth. Unit twists give 1 m/s of the camera centre at t_mid
// (rotate: 1 rad/s). `duration` (s, the rendered span) and `seed` shape the
// hand-held path only.
CameraPath MakeCameraPath(CameraPathType type, const StereoScene& scene, double t_mid,
                          double arc_fixation_factor, double duration = 1.0, std::uint64_t seed = 0);

// Image motion over an exposure (HR px) of the pixels with depth > 0: each is
// back-projected with `depth_end` at T_world_end and projected at T_world_start.
struct MotionStats {
  double min_px = 0.0;
  double median_px = 0.0;
  double max_px = 0.0;
  int num_pixels = 0;
};
MotionStats MeasureImageMotion(const PinholeCamera& camera, const cv::Mat& depth_end,
                               const SE3& T_world_start, const SE3& T_world_end);

// ------------------------------------------------------------- synthesis

// Options of SynthesizeSequence and of the synthesize_sequence tool.
struct SynthesisOptions {
  int num_frames = 10;                             // frames to write (--frames)
  int scale = 2;                                   // SR factor: LR = box-downsampled HR (--scale)
  double exposure_ratio = 0.8;                     // exposure / frame interval, in (0, 1] (--exposure-ratio)
  CameraPathType path = CameraPathType::kLateral;  // --path
  double noise_sigma = 0.0;                        // Gaussian noise on the LR frames, 8-bit units (--noise)
  // Seed of the noise, the hand-held path and the gains; equal seeds give
  // equal output (--seed).
  std::uint64_t seed = 0;
  double blur_px = 14.0;  // target median HR image motion per exposure (--blur-px)
  int subframes = 200;    // renders averaged per exposure, > the estimator's M (--subframes)
  double fps = 30.0;      // frame rate; stamps are t_c = (i + 1) / fps (--fps)
  // HR size; 0 = automatic (largest centred crop of the scene size, divisible
  // by the scale, whose pixels stay covered by the views along the whole path).
  int hr_width = 0;                  // --hr-width
  int hr_height = 0;                 // --hr-height
  double arc_fixation_factor = 2.0;  // arc: fixation point at this x median depth (--arc-fixation)
  // forward: total z travel over the sequence <= this x the nearest depth, so
  // the last camera stays >= 0.8 x that depth away (--forward-cap).
  double forward_travel_cap = 0.4;
  // Automatic crop: the worst pose along the path may leave at most this
  // fraction of the HR pixels uncovered.
  double max_hole_fraction = 0.01;
  // Per-frame gain drawn from [1 - G, 1 + G], multiplied into the blurred
  // frame and its gt latent (--gain-jitter), G in [0, 0.5].
  double gain_jitter = 0.0;
  // Rolling shutter: readout_time = this x the frame interval (docs/file_formats.md#rolling-shutter),
  // in [0, 1]; 0 = global shutter (--readout-ratio).
  double readout_ratio = 0.0;

  // Throws InputError naming the option and the problem.
  void Check() const;
};

struct FrameSynthesisStats {
  MotionStats blur;                   // image motion over the exposure, HR px
  double hole_fraction_latent = 0.0;  // of the sharp render at t_c
  double hole_fraction_max = 0.0;     // worst over the exposure's sub-frames
  double gain = 1.0;                  // multiplied into the frame and its latent
};

struct SynthesisResult {
  Sequence sequence;  // LR frames + gt/ (HR latent, depth, poses)
  PinholeCamera hr_camera;
  PinholeCamera lr_camera;
  CameraPath path;
  // Median blur of the middle frame after calibration (handheld: the median
  // over the frames of each frame's median).
  double achieved_blur_px = 0.0;
  bool speed_capped = false;  // forward path limited by forward_travel_cap
  std::vector<FrameSynthesisStats> frame_stats;
  double seconds = 0.0;
};

// Frame i: stamp t_c = (i + 1) / fps, exposure = exposure_ratio / fps.
double FrameStamp(const SynthesisOptions& options, int index);
double FrameExposure(const SynthesisOptions& options);
// readout_ratio / fps (s): row y of H LR rows is exposed readout * y / H later.
double ReadoutTime(const SynthesisOptions& options);

// Automatic HR camera: focal length of the scene, principal point at the
// centre, size a centred crop of the scene image (see SynthesisOptions).
PinholeCamera ChooseHrCamera(const StereoScene& scene, const SceneRenderer& renderer, const CameraPath& path,
                             const SynthesisOptions& options);

// Sets path->speed so that the median image motion over the middle frame's
// exposure equals options.blur_px (capped for the forward and handheld paths;
// handheld, whose speed varies: the median over the frames of each frame's
// median). Returns the
// achieved median; *capped tells whether the cap was hit.
double CalibratePathSpeed(const StereoScene& scene, const SceneRenderer& renderer,
                          const PinholeCamera& camera, const SynthesisOptions& options, CameraPath* path,
                          bool* capped);

// The whole pipeline; `log` (may be null) receives progress lines.
SynthesisResult SynthesizeSequence(const StereoScene& scene, const SynthesisOptions& options,
                                   std::ostream* log = nullptr);

// gt/synthesis.yaml: options, calibration, path and per-frame blur statistics.
void WriteSynthesisYaml(const std::string& path, const StereoScene& scene, const SynthesisOptions& options,
                        const SynthesisResult& result);

}  // namespace deblur_sr_mvs
