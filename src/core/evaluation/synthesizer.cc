#include "deblur_sr_mvs/core/evaluation/synthesizer.h"
#include "deblur_sr_mvs/core/common/options_check.h"
#include "deblur_sr_mvs/core/common/text.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <limits>
#include <ostream>
#include <sstream>

#include <omp.h>
#include <yaml-cpp/yaml.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace deblur_sr_mvs {
namespace {

namespace fs = std::filesystem;

// Middlebury 2005/2006 calibration (data/middlebury/SOURCES.md): full-size
// focal length, the stored images are third-size, 160 mm between view1 and view5.
constexpr double kMiddleburyFullFocalPx = 3740.0;
constexpr double kMiddleburyDownsampling = 3.0;
constexpr double kMiddleburyBaselineM = 0.160;

// Points closer than this to the virtual camera are not rendered.
constexpr float kNearPlaneM = 1e-3f;

cv::Mat ReadSceneImage(const fs::path& file, int flags) {
  if (!fs::exists(file)) throw InputError(file.string() + ": file not found");
  cv::Mat image = cv::imread(file.string(), flags);
  if (image.empty()) throw InputError(file.string() + ": cannot read the image");
  return image;
}

int ReadDmin(const fs::path& file) {
  if (!fs::exists(file)) throw InputError(file.string() + ": file not found");
  std::ifstream in(file);
  if (!in) throw InputError(file.string() + ": cannot open the file");
  std::stringstream buffer;
  buffer << in.rdbuf();
  std::string text = buffer.str();
  // One integer; whitespace and CRLF line endings are allowed around it.
  const auto first = text.find_first_not_of(" \t\r\n");
  const auto last = text.find_last_not_of(" \t\r\n");
  if (first == std::string::npos) throw InputError(file.string() + ": empty, expected an integer");
  text = text.substr(first, last - first + 1);
  std::size_t used = 0;
  long value = 0;
  try {
    value = std::stol(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size()) {
    throw InputError(file.string() + ": expected one integer, got \"" + text.substr(0, 40) + "\"");
  }
  if (value < 0 || value > 100000) {
    throw InputError(file.string() + ": dmin " + std::to_string(value) + " is out of range");
  }
  return static_cast<int>(value);
}

double Median(std::vector<float>* values) {
  if (values->empty()) return 0.0;
  auto middle = values->begin() + values->size() / 2;
  std::nth_element(values->begin(), middle, values->end());
  return *middle;
}

// The scene's image size and focal length, with the principal point halfway
// between the two views' (view5's is shifted by the crop offset dmin/3): the
// midpoint camera then sees the middle of what the two views cover together.
PinholeCamera ProbeCamera(const StereoScene& scene) {
  const PinholeCamera& view1 = scene.views[0].camera;
  const PinholeCamera& view5 = scene.views[1].camera;
  return PinholeCamera(view1.width, view1.height, scene.focal_px, scene.focal_px, 0.5 * (view1.cx + view5.cx),
                       0.5 * (view1.cy + view5.cy));
}

// The centred width x height crop of the probe camera's image.
PinholeCamera CentredCrop(const PinholeCamera& probe, int width, int height) {
  return PinholeCamera(width, height, probe.fx, probe.fy, probe.cx - 0.5 * (probe.width - width),
                       probe.cy - 0.5 * (probe.height - height));
}

double PathStart(const SynthesisOptions& options) {
  return FrameStamp(options, 0) - FrameExposure(options);
}
// The path's shape and t_mid depend on these frame times only, so that a
// rolling shutter renders the same path as the global shutter.
double PathEnd(const SynthesisOptions& options) {
  return FrameStamp(options, options.num_frames - 1);
}
// The last frame's bottom row closes a readout time after its stamp.
double RenderedEnd(const SynthesisOptions& options) {
  return PathEnd(options) + ReadoutTime(options);
}

// Depth of `result` with its holes set to 0 (unknown): measured blur then
// uses only pixels some view actually covered.
cv::Mat CoveredDepth(const RenderResult& result) {
  cv::Mat depth = result.depth.clone();
  depth.setTo(0.0f, result.hole_mask);
  return depth;
}

// Pinhole projection of n points (structure of arrays); a free function with
// restrict pointers so that the compiler vectorises it.
void ProjectPoints(int n, const Eigen::Matrix3f& R, const Eigen::Vector3f& t, const PinholeCamera& camera,
                   const float* __restrict__ px, const float* __restrict__ py, const float* __restrict__ pz,
                   float* __restrict__ us, float* __restrict__ vs, float* __restrict__ zs) {
  const float r00 = R(0, 0), r01 = R(0, 1), r02 = R(0, 2), r10 = R(1, 0), r11 = R(1, 1), r12 = R(1, 2),
              r20 = R(2, 0), r21 = R(2, 1), r22 = R(2, 2);
  const float tx = t.x(), ty = t.y(), tz = t.z();
  const float fx = camera.fx, fy = camera.fy, cx = camera.cx, cy = camera.cy;
  for (int i = 0; i < n; ++i) {
    const float xc = r00 * px[i] + r01 * py[i] + r02 * pz[i] + tx;
    const float yc = r10 * px[i] + r11 * py[i] + r12 * pz[i] + ty;
    const float zc = r20 * px[i] + r21 * py[i] + r22 * pz[i] + tz;
    const float inv_z = 1.0f / zc;
    us[i] = fx * xc * inv_z + cx;
    vs[i] = fy * yc * inv_z + cy;
    zs[i] = zc;
  }
}

}  // namespace

// ------------------------------------------------------------------- scene

StereoScene LoadMiddleburyScene(const std::string& folder) {
  const fs::path root(folder);
  if (!fs::is_directory(root)) throw InputError(folder + ": scene folder not found");

  StereoScene scene;
  scene.folder = folder;
  scene.focal_px = kMiddleburyFullFocalPx / kMiddleburyDownsampling;
  scene.baseline_m = kMiddleburyBaselineM;
  scene.dmin = ReadDmin(root / "dmin.txt");

  const char* kImageNames[2] = {"view1.png", "view5.png"};
  const char* kDisparityNames[2] = {"disp1.png", "disp5.png"};
  cv::Size size;
  std::vector<float> depths;
  for (int v = 0; v < 2; ++v) {
    SceneView& view = scene.views[v];
    view.image = ReadSceneImage(root / kImageNames[v], cv::IMREAD_COLOR);
    const fs::path disparity_file = root / kDisparityNames[v];
    const cv::Mat disparity = ReadSceneImage(disparity_file, cv::IMREAD_UNCHANGED);
    if (disparity.type() != CV_8UC1) {
      throw InputError(disparity_file.string() + ": expected an 8-bit single-channel disparity image");
    }
    if (v == 0) size = view.image.size();
    if (view.image.size() != size) {
      throw InputError((root / kImageNames[v]).string() + ": size " + SizeText(view.image) +
                       " differs from view1.png " + std::to_string(size.width) + "x" +
                       std::to_string(size.height));
    }
    if (disparity.size() != size) {
      throw InputError(disparity_file.string() + ": size " + SizeText(disparity) +
                       " differs from view1.png " + std::to_string(size.width) + "x" +
                       std::to_string(size.height));
    }
    // Z = f_full B / (I + dmin) with I the stored value (~full-size disparity).
    view.depth.create(size, CV_32FC1);
    for (int y = 0; y < size.height; ++y) {
      const uint8_t* in = disparity.ptr<uint8_t>(y);
      float* out = view.depth.ptr<float>(y);
      for (int x = 0; x < size.width; ++x) {
        const int total = in[x] + scene.dmin;
        out[x] = (in[x] == 0 || total <= 0)
                     ? 0.0f
                     : static_cast<float>(kMiddleburyFullFocalPx * kMiddleburyBaselineM / total);
        if (out[x] > 0.0f) depths.push_back(out[x]);
      }
    }
  }
  if (depths.empty()) throw InputError(folder + ": no known disparity in disp1.png or disp5.png");

  // view1 has its principal point at the image centre; view5 sits 160 mm to
  // the right and its principal point is shifted by the crop offset dmin/3.
  const double cx1 = (size.width - 1) / 2.0;
  const double cy = (size.height - 1) / 2.0;
  scene.views[0].camera = PinholeCamera(size.width, size.height, scene.focal_px, scene.focal_px, cx1, cy);
  scene.views[1].camera = PinholeCamera(size.width, size.height, scene.focal_px, scene.focal_px,
                                        cx1 + scene.dmin / kMiddleburyDownsampling, cy);
  scene.views[0].T_world_cam = SE3();
  scene.views[1].T_world_cam = SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(scene.baseline_m, 0.0, 0.0));

  scene.min_depth = *std::min_element(depths.begin(), depths.end());
  scene.max_depth = *std::max_element(depths.begin(), depths.end());
  scene.median_depth = Median(&depths);
  return scene;
}

StereoScene ZoomScene(const StereoScene& scene, double zoom) {
  if (!(zoom >= 1.0 && zoom <= 4.0)) {
    throw InputError("scene zoom must be in [1, 4], got " + std::to_string(zoom));
  }
  StereoScene zoomed = scene;
  zoomed.focal_px = scene.focal_px * zoom;
  for (int v = 0; v < 2; ++v) {
    const SceneView& in = scene.views[v];
    SceneView& out = zoomed.views[v];
    const cv::Size size(static_cast<int>(std::lround(in.image.cols * zoom)),
                        static_cast<int>(std::lround(in.image.rows * zoom)));
    cv::resize(in.image, out.image, size, 0, 0, cv::INTER_CUBIC);
    cv::resize(in.depth, out.depth, size, 0, 0, cv::INTER_NEAREST);
    // Pixel centres: X' + 0.5 = zoom (X + 0.5).
    out.camera = PinholeCamera(size.width, size.height, in.camera.fx * zoom, in.camera.fy * zoom,
                               zoom * (in.camera.cx + 0.5) - 0.5, zoom * (in.camera.cy + 0.5) - 0.5);
  }
  return zoomed;
}

// --------------------------------------------------------------- renderer

void SceneRenderer::Points::Reserve(std::size_t n) {
  for (std::vector<float>* values : {&x, &y, &z, &b, &g, &r}) values->reserve(n);
}

void SceneRenderer::Points::Append(const Points& other, std::size_t i) {
  x.push_back(other.x[i]);
  y.push_back(other.y[i]);
  z.push_back(other.z[i]);
  b.push_back(other.b[i]);
  g.push_back(other.g[i]);
  r.push_back(other.r[i]);
}

SceneRenderer::SceneRenderer(const StereoScene& scene) {
  for (int v = 0; v < 2; ++v) {
    const SceneView& view = scene.views[v];
    view_centres_world_[v] = view.T_world_cam.translation();
    Points& points = points_[v];
    points.Reserve(view.image.total());
    for (int y = 0; y < view.image.rows; ++y) {
      const float* depth = view.depth.ptr<float>(y);
      const cv::Vec3b* colour = view.image.ptr<cv::Vec3b>(y);
      for (int x = 0; x < view.image.cols; ++x) {
        if (!(depth[x] > 0.0f)) continue;  // unknown disparity: no point
        const Eigen::Vector3d p_world = view.T_world_cam * (depth[x] * view.camera.Ray(x, y));
        points.x.push_back(static_cast<float>(p_world.x()));
        points.y.push_back(static_cast<float>(p_world.y()));
        points.z.push_back(static_cast<float>(p_world.z()));
        points.b.push_back(colour[x][0]);
        points.g.push_back(colour[x][1]);
        points.r.push_back(colour[x][2]);
      }
    }
  }
}

SceneRenderer SceneRenderer::CulledFor(const PinholeCamera& camera,
                                       const std::vector<SE3>& T_world_cams) const {
  SceneRenderer culled;
  culled.view_centres_world_ = view_centres_world_;
  const std::size_t num_poses = T_world_cams.size();
  std::vector<SE3> T_cam_worlds;
  for (const SE3& T : T_world_cams) T_cam_worlds.push_back(T.Inverse());
  constexpr double kBehind = std::numeric_limits<double>::quiet_NaN();
  for (int v = 0; v < 2; ++v) {
    const Points& points = points_[v];
    const std::size_t n = points.x.size();
    // Projections at every pose (NaN: behind the camera), and the largest
    // image step between consecutive poses.
    std::vector<Eigen::Vector2d> projections(n * num_poses);
    double max_step = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
      const Eigen::Vector3d p_world(points.x[i], points.y[i], points.z[i]);
      for (std::size_t k = 0; k < num_poses; ++k) {
        const Eigen::Vector3d p_cam = T_cam_worlds[k] * p_world;
        Eigen::Vector2d& uv = projections[i * num_poses + k];
        uv = p_cam.z() > kNearPlaneM ? camera.Project(p_cam) : Eigen::Vector2d(kBehind, kBehind);
        if (k > 0) {
          const double step = (uv - projections[i * num_poses + k - 1]).norm();
          if (std::isfinite(step)) max_step = std::max(max_step, step);
        }
      }
    }
    // A point whose image path crosses the image between two poses is within
    // half a step of it at one of them.
    const double margin = 0.5 * max_step + 2.0;
    Points& kept = culled.points_[v];
    kept.Reserve(n);
    for (std::size_t i = 0; i < n; ++i) {
      for (std::size_t k = 0; k < num_poses; ++k) {
        const Eigen::Vector2d& uv = projections[i * num_poses + k];
        if (uv.x() > -1.0 - margin && uv.y() > -1.0 - margin && uv.x() < camera.width + margin &&
            uv.y() < camera.height + margin) {
          kept.Append(points, i);
          break;
        }
      }
    }
  }
  return culled;
}

RenderResult SceneRenderer::Render(const PinholeCamera& camera, const SE3& T_world_cam,
                                   const RenderOptions& options) const {
  RenderWorkspace workspace;
  RenderResult result;
  Render(camera, T_world_cam, options, &workspace, &result);
  return result;
}

namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

// The image grid and the thresholds of RenderOptions, as every rendering
// step uses them (in float).
struct SplatGrid {
  int width = 0;
  int height = 0;
  int num_pixels = 0;
  float min_weight = 0.0f;      // min_splat_weight
  float coverage = 0.0f;        // coverage_weight
  float tolerance_high = 0.0f;  // 1 + depth_tolerance
  float tolerance_low = 0.0f;   // 1 - depth_tolerance
};

SplatGrid MakeSplatGrid(const PinholeCamera& camera, const RenderOptions& options) {
  SplatGrid grid;
  grid.width = camera.width;
  grid.height = camera.height;
  grid.num_pixels = camera.width * camera.height;
  grid.min_weight = options.min_splat_weight;
  grid.coverage = options.coverage_weight;
  grid.tolerance_high = 1.0f + options.depth_tolerance;
  grid.tolerance_low = 1.0f - options.depth_tolerance;
  return grid;
}

// The primary view renders every pixel: empty accumulators and z-buffer.
void ClearPrimaryBuffers(const SplatGrid& grid, std::vector<float>* zbuffer, std::vector<float>* accum) {
  accum->assign(static_cast<std::size_t>(grid.num_pixels) * 5, 0.0f);
  zbuffer->assign(grid.num_pixels, kInf);
}

// The secondary only renders where the primary does not cover: a z-buffer of
// -inf elsewhere rejects every splat, only the uncovered accumulators need
// clearing (the composite reads no others), and `useful` flags the footprint
// corners (x0, y0), offset by one, whose 2x2 footprint has an uncovered pixel,
// so most points skip at one byte.
void MaskSecondaryBuffers(const SplatGrid& grid, const std::vector<float>& primary_accum,
                          std::vector<float>* zbuffer, std::vector<float>* accum,
                          std::vector<uint8_t>* useful) {
  const int width = grid.width;
  const int num_pixels = grid.num_pixels;
  accum->resize(static_cast<std::size_t>(num_pixels) * 5);
  zbuffer->resize(num_pixels);
  useful->assign(static_cast<std::size_t>(width + 1) * (grid.height + 1), 0);
  const float* a = primary_accum.data();
  for (int p = 0; p < num_pixels; ++p) {
    const bool covered = a[5 * p + 3] >= grid.coverage;
    (*zbuffer)[p] = covered ? -kInf : kInf;
    if (covered) continue;
    std::fill_n(&(*accum)[static_cast<std::size_t>(p) * 5], 5, 0.0f);
    const int x = p % width, y = p / width;
    uint8_t* corner = &(*useful)[static_cast<std::size_t>(y) * (width + 1) + x];
    corner[0] = corner[1] = corner[width + 1] = corner[width + 2] = 1;
  }
}

// Pass 1: nearest depth per pixel over the splats with a real share of it.
// The splats touching pixels this view renders are kept for pass 2 with their
// footprint: top-left pixel (x0, y0), bilinear fractions. `useful` (secondary
// view only, else null) skips footprints without an uncovered pixel.
void SplatDepths(const SplatGrid& grid, int n, const float* us, const float* vs, const float* zs,
                 const uint8_t* useful, float* zb, std::vector<RenderWorkspace::Splat>* active) {
  const int width = grid.width, height = grid.height;
  const float min_weight = grid.min_weight;
  active->clear();
  for (int i = 0; i < n; ++i) {
    const float u = us[i], v = vs[i], z = zs[i];
    if (!(z >= kNearPlaneM && u > -1.0f && v > -1.0f && u < width && v < height)) continue;
    const int x0 = static_cast<int>(u + 1.0f) - 1;  // floor for u > -1
    const int y0 = static_cast<int>(v + 1.0f) - 1;
    // u + 1 can round up to width + 1 in float for u just below width
    // (found by AddressSanitizer): such a splat has no share inside.
    if (x0 >= width || y0 >= height) continue;
    if (useful != nullptr && !useful[static_cast<std::size_t>(y0 + 1) * (width + 1) + (x0 + 1)]) {
      continue;
    }
    const float ax = u - x0, ay = v - y0;
    const float weights[4] = {(1.0f - ax) * (1.0f - ay), ax * (1.0f - ay), (1.0f - ax) * ay, ax * ay};
    const bool inside = x0 >= 0 && y0 >= 0 && x0 + 1 < width && y0 + 1 < height;
    if (inside) {
      float* cell = zb + y0 * width + x0;
      float* cells[4] = {cell, cell + 1, cell + width, cell + width + 1};
      for (int c = 0; c < 4; ++c) {
        *cells[c] = std::min(*cells[c], weights[c] >= min_weight ? z : kInf);
      }
    } else {
      for (int c = 0; c < 4; ++c) {
        const int x = x0 + (c & 1), y = y0 + (c >> 1);
        if (x < 0 || y < 0 || x >= width || y >= height || weights[c] < min_weight) continue;
        zb[y * width + x] = std::min(zb[y * width + x], z);
      }
    }
    active->push_back({i, x0, y0, inside, ax, ay});
  }
}

// Pass 2: blend colour and depth of the splats on the front surface, within
// the depth tolerance of the z-buffer on both sides (a nearer splat there had
// too little weight to count and would fatten edges). `bgr` are the points'
// colour channels.
void BlendFrontSplats(const SplatGrid& grid, const std::vector<RenderWorkspace::Splat>& active,
                      const float* zs, const float* const bgr[3], const float* zb, float* acc) {
  const int width = grid.width, height = grid.height;
  const float* pb = bgr[0];
  const float* pg = bgr[1];
  const float* pr = bgr[2];
  for (const RenderWorkspace::Splat& splat : active) {
    const int i = splat.point;
    const float z = zs[i];
    const float ax = splat.ax, ay = splat.ay;
    const float weights[4] = {(1.0f - ax) * (1.0f - ay), ax * (1.0f - ay), (1.0f - ax) * ay, ax * ay};
    const float colour[3] = {pb[i], pg[i], pr[i]};
    for (int c = 0; c < 4; ++c) {
      const int x = splat.x0 + (c & 1), y = splat.y0 + (c >> 1);
      if (!splat.inside && (x < 0 || y < 0 || x >= width || y >= height)) continue;
      const int index = y * width + x;
      const float front = zb[index];
      const bool on_front =
          z <= front * grid.tolerance_high && (z >= front * grid.tolerance_low || front == kInf);
      const float w = on_front ? weights[c] : 0.0f;
      float* a = acc + static_cast<std::size_t>(index) * 5;
      a[0] += w * colour[0];
      a[1] += w * colour[1];
      a[2] += w * colour[2];
      a[3] += w;
      a[4] += w * z;
    }
  }
}

// Composite: the primary where it covers, else the secondary (null when only
// one view rendered); a faint splat still beats a guess; the rest are holes,
// listed in `holes`.
void CompositeViews(const SplatGrid& grid, const float* acc_primary, const float* acc_secondary,
                    std::vector<int>* holes, RenderResult* result) {
  const int width = grid.width, height = grid.height;
  result->image.create(height, width, CV_32FC3);
  result->depth.create(height, width, CV_32FC1);
  result->hole_mask.create(height, width, CV_8UC1);
  holes->clear();
  int num_secondary = 0;
  float* image = result->image.ptr<float>();
  float* depth = result->depth.ptr<float>();
  uint8_t* mask = result->hole_mask.ptr<uint8_t>();
  for (int index = 0; index < grid.num_pixels; ++index) {
    const float* a = acc_primary + static_cast<std::size_t>(index) * 5;
    const float* b = acc_secondary ? acc_secondary + static_cast<std::size_t>(index) * 5 : nullptr;
    const float wa = a[3];
    const float wb = b ? b[3] : 0.0f;
    const float* chosen = nullptr;
    if (wa >= grid.coverage) {
      chosen = a;
    } else if (wb >= grid.coverage) {
      chosen = b;
    } else if (std::max(wa, wb) >= grid.min_weight) {
      chosen = wa >= wb ? a : b;
    }
    if (chosen) {
      const float inv = 1.0f / chosen[3];
      image[3 * index + 0] = chosen[0] * inv;
      image[3 * index + 1] = chosen[1] * inv;
      image[3 * index + 2] = chosen[2] * inv;
      depth[index] = chosen[4] * inv;
      mask[index] = 0;
      num_secondary += chosen == b;
    } else {
      image[3 * index + 0] = image[3 * index + 1] = image[3 * index + 2] = 0.0f;
      depth[index] = 0.0f;
      mask[index] = 255;
      holes->push_back(index);
    }
  }
  result->num_holes = static_cast<int>(holes->size());
  result->num_secondary = num_secondary;
}

// Hole filling grows inwards one ring per pass from the 8-neighbours; the
// farthest neighbour (the background a disocclusion reveals) sets the depth
// and the neighbours near that depth the colour. Values are committed after
// each pass so that the growth is isotropic. Starts from workspace->holes.
void FillHoles(const SplatGrid& grid, RenderWorkspace* workspace, RenderResult* result) {
  constexpr float kBackgroundTolerance = 0.03f;
  const int width = grid.width, height = grid.height;
  float* image = result->image.ptr<float>();
  float* depth = result->depth.ptr<float>();
  std::vector<int>& holes = workspace->holes;
  std::vector<int>& next_holes = workspace->next_holes;
  std::vector<int>& filled = workspace->filled;
  std::vector<float>& fill = workspace->fill_values;
  while (!holes.empty()) {
    next_holes.clear();
    filled.clear();
    fill.clear();
    for (const int index : holes) {
      const int x = index % width, y = index / width;
      float z_max = 0.0f;
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          const int xn = x + dx, yn = y + dy;
          if (xn < 0 || yn < 0 || xn >= width || yn >= height) continue;
          z_max = std::max(z_max, depth[yn * width + xn]);
        }
      }
      if (z_max <= 0.0f) {
        next_holes.push_back(index);
        continue;
      }
      float sum[3] = {0.0f, 0.0f, 0.0f};
      int count = 0;
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          const int xn = x + dx, yn = y + dy;
          if (xn < 0 || yn < 0 || xn >= width || yn >= height) continue;
          const int n = yn * width + xn;
          if (depth[n] < z_max * (1.0f - kBackgroundTolerance)) continue;
          for (int c = 0; c < 3; ++c) sum[c] += image[3 * n + c];
          ++count;
        }
      }
      filled.push_back(index);
      fill.insert(fill.end(), {sum[0] / count, sum[1] / count, sum[2] / count, z_max});
    }
    if (filled.empty()) break;  // nothing reachable (cannot happen with >= 1 covered pixel)
    for (std::size_t f = 0; f < filled.size(); ++f) {
      const int index = filled[f];
      image[3 * index + 0] = fill[4 * f + 0];
      image[3 * index + 1] = fill[4 * f + 1];
      image[3 * index + 2] = fill[4 * f + 2];
      depth[index] = fill[4 * f + 3];
    }
    holes.swap(next_holes);
  }
}

}  // namespace

int SceneRenderer::PrimaryView(const SE3& T_world_cam) const {
  // A camera on the views' bisector (the rotate path turns about the
  // midpoint) takes view 0: compared exactly, rounding would pick either
  // view from one pose to the next.
  const double baseline = (view_centres_world_[1] - view_centres_world_[0]).norm();
  const Eigen::Vector3d centre = T_world_cam.translation();
  const double nearer_by =
      (centre - view_centres_world_[0]).norm() - (centre - view_centres_world_[1]).norm();
  return nearer_by > 1e-9 * baseline ? 1 : 0;
}

void SceneRenderer::Render(const PinholeCamera& camera, const SE3& T_world_cam, const RenderOptions& options,
                           RenderWorkspace* workspace, RenderResult* result) const {
  const SplatGrid grid = MakeSplatGrid(camera, options);
  const SE3 T_cam_world = T_world_cam.Inverse();
  const Eigen::Matrix3f R = T_cam_world.rotation().cast<float>();
  const Eigen::Vector3f t = T_cam_world.translation().cast<float>();

  int primary = options.primary_view == 0 || options.primary_view == 1 ? options.primary_view
                                                                       : PrimaryView(T_world_cam);
  int num_views = 2;
  if (options.only_view == 0 || options.only_view == 1) {
    primary = options.only_view;
    num_views = 1;
  }
  const int order[2] = {primary, 1 - primary};

  for (int k = 0; k < num_views; ++k) {
    const int view = order[k];
    const Points& points = points_[view];
    const int n = static_cast<int>(points.x.size());
    const bool secondary = k == 1;
    std::vector<float>& zbuffer = workspace->zbuffer[view];
    std::vector<float>& accum = workspace->accum[view];
    if (secondary) {
      MaskSecondaryBuffers(grid, workspace->accum[order[0]], &zbuffer, &accum, &workspace->useful);
    } else {
      ClearPrimaryBuffers(grid, &zbuffer, &accum);
    }
    // Projection, vectorisable (no branches, structure of arrays).
    workspace->u.resize(n);
    workspace->v.resize(n);
    workspace->z.resize(n);
    ProjectPoints(n, R, t, camera, points.x.data(), points.y.data(), points.z.data(), workspace->u.data(),
                  workspace->v.data(), workspace->z.data());
    SplatDepths(grid, n, workspace->u.data(), workspace->v.data(), workspace->z.data(),
                secondary ? workspace->useful.data() : nullptr, zbuffer.data(), &workspace->active);
    const float* const bgr[3] = {points.b.data(), points.g.data(), points.r.data()};
    BlendFrontSplats(grid, workspace->active, workspace->z.data(), bgr, zbuffer.data(), accum.data());
  }

  CompositeViews(grid, workspace->accum[order[0]].data(),
                 num_views == 2 ? workspace->accum[order[1]].data() : nullptr, &workspace->holes, result);
  if (!options.fill_holes || workspace->holes.empty() || result->num_holes == grid.num_pixels) return;
  FillHoles(grid, workspace, result);
}

// ------------------------------------------------------------ camera paths

std::string CameraPathName(CameraPathType type) {
  switch (type) {
    case CameraPathType::kLateral:
      return "lateral";
    case CameraPathType::kArc:
      return "arc";
    case CameraPathType::kForward:
      return "forward";
    case CameraPathType::kHandheld:
      return "handheld";
    case CameraPathType::kRotate:
      return "rotate";
  }
  return "unknown";
}

CameraPathType ParseCameraPathType(const std::string& name) {
  if (name == "lateral") return CameraPathType::kLateral;
  if (name == "arc") return CameraPathType::kArc;
  if (name == "forward") return CameraPathType::kForward;
  if (name == "handheld") return CameraPathType::kHandheld;
  if (name == "rotate") return CameraPathType::kRotate;
  throw InputError("--path: unknown path \"" + name +
                   "\" (expected lateral, arc, forward, handheld or rotate)");
}

namespace {

double SumOfSinusoids(const std::vector<PathSinusoid>& terms, double u) {
  double sum = 0.0;
  for (const PathSinusoid& term : terms)
    sum += term.amplitude * std::sin(2.0 * M_PI * term.cycles * u + term.phase);
  return sum;
}

// SplitMix64: a small, portable generator, so that a seed gives the same
// path and gains on every platform (std:: distributions do not promise that).
class SeededUniform {
 public:
  explicit SeededUniform(std::uint64_t seed) : state_(seed) {}
  double Next(double low, double high) {
    state_ += 0x9E3779B97F4A7C15ull;
    std::uint64_t z = state_;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    z ^= z >> 31;
    return low + (high - low) * static_cast<double>(z >> 11) * 0x1.0p-53;
  }

 private:
  std::uint64_t state_;
};

// Stream offsets of the seed: the noise keeps cv::RNG(seed) as before.
constexpr std::uint64_t kHandheldStream = 0x68616E6468656C64ull;  // "handheld"
constexpr std::uint64_t kGainStream = 0x6761696E6A697474ull;      // "gainjitt"

// Two components per axis of 0.3 to 1.5 cycles over the path: smooth over an
// exposure. `relative_rate` bounds each component's peak rate (per unit
// speed), so the amplitude is relative_rate * duration / (2 pi cycles).
std::vector<PathSinusoid> RandomSinusoids(SeededUniform* uniform, double duration, double rate_low,
                                          double rate_high) {
  std::vector<PathSinusoid> terms(2);
  for (PathSinusoid& term : terms) {
    term.cycles = uniform->Next(0.3, 1.5);
    term.phase = uniform->Next(0.0, 2.0 * M_PI);
    term.amplitude = uniform->Next(rate_low, rate_high) * duration / (2.0 * M_PI * term.cycles);
  }
  return terms;
}

// Ratio of the fastest to the slowest centre speed over the path (u in
// [-1/2, 1/2]) for a drift of 1 m/s along `drift` plus the shake.
double SpeedRatio(const HandheldShape& shape, const Eigen::Vector3d& drift) {
  constexpr int kSamples = 41;
  double slowest = std::numeric_limits<double>::infinity(), fastest = 0.0;
  for (int k = 0; k < kSamples; ++k) {
    const double u = -0.5 + static_cast<double>(k) / (kSamples - 1);
    Eigen::Vector3d velocity = drift;
    for (int axis = 0; axis < 3; ++axis) {
      for (const PathSinusoid& term : shape.translation[axis]) {
        const double omega = 2.0 * M_PI * term.cycles;
        velocity[axis] += term.amplitude * omega / shape.duration * std::cos(omega * u + term.phase);
      }
    }
    slowest = std::min(slowest, velocity.norm());
    fastest = std::max(fastest, velocity.norm());
  }
  return fastest / std::max(slowest, 1e-12);
}

// Hand-held shake: along the drift (x, the baseline) the velocity varies by
// up to +-60 % (never reversing), a smaller sway in y and z; rotation rates
// whose image motion is up to ~40 % of the drift's at the median depth.
// Shapes whose speed hardly varies (fastest < 1.25 x slowest, ~5 % of draws)
// are drawn again from the same stream, so that every seed has a
// non-constant velocity.
HandheldShape MakeHandheldShape(double duration, double median_depth, const Eigen::Vector3d& drift,
                                std::uint64_t seed) {
  constexpr double kMinSpeedRatio = 1.25;
  constexpr int kMaxDraws = 1000;
  const double kTranslationRates[3][2] = {{0.15, 0.3}, {0.08, 0.2}, {0.05, 0.1}};
  const double kRotationRates[3][2] = {{0.08, 0.2}, {0.08, 0.2}, {0.05, 0.1}};  // pitch, yaw, roll
  SeededUniform uniform(seed ^ kHandheldStream);
  HandheldShape shape;
  shape.duration = duration;
  for (int draw = 0; draw < kMaxDraws; ++draw) {
    for (int axis = 0; axis < 3; ++axis) {
      shape.translation[axis] =
          RandomSinusoids(&uniform, duration, kTranslationRates[axis][0], kTranslationRates[axis][1]);
    }
    if (SpeedRatio(shape, drift) >= kMinSpeedRatio) break;
  }
  for (int axis = 0; axis < 3; ++axis) {
    shape.rotation[axis] = RandomSinusoids(&uniform, duration, kRotationRates[axis][0] / median_depth,
                                           kRotationRates[axis][1] / median_depth);
  }
  return shape;
}

}  // namespace

SE3 CameraPath::PoseAt(double t) const {
  if (type != CameraPathType::kHandheld) return SE3::Exp((t - t_mid) * speed * unit_twist) * T_world_mid;
  const double u = (t - t_mid) / handheld.duration;
  Eigen::Vector3d shake, angles;
  for (int axis = 0; axis < 3; ++axis) {
    shake[axis] = SumOfSinusoids(handheld.translation[axis], u);
    angles[axis] = SumOfSinusoids(handheld.rotation[axis], u);
  }
  const Eigen::Vector3d centre =
      T_world_mid.translation() + speed * ((t - t_mid) * unit_twist.head<3>() + shake);
  return SE3(SO3Exp(speed * angles) * T_world_mid.rotation(), centre);
}

CameraPath MakeCameraPath(CameraPathType type, const StereoScene& scene, double t_mid,
                          double arc_fixation_factor, double duration, std::uint64_t seed) {
  CameraPath path;
  path.type = type;
  path.t_mid = t_mid;
  const Eigen::Vector3d c1 = scene.views[0].T_world_cam.translation();
  const Eigen::Vector3d c5 = scene.views[1].T_world_cam.translation();
  const Eigen::Vector3d midpoint = 0.5 * (c1 + c5);
  path.T_world_mid = SE3(Eigen::Matrix3d::Identity(), midpoint);
  const Eigen::Vector3d baseline_direction = (c5 - c1).normalized();
  switch (type) {
    case CameraPathType::kLateral:
      path.unit_twist.head<3>() = baseline_direction;
      break;
    case CameraPathType::kForward:
      // Mostly towards the scene; the small sideways part keeps some parallax
      // at the image centre, where forward motion alone gives none.
      path.unit_twist.head<3>() = (0.3 * baseline_direction + Eigen::Vector3d::UnitZ()).normalized();
      break;
    case CameraPathType::kArc: {
      // Rotation about the vertical (y, pointing down) axis through the
      // fixation point F: twist (rho, w) with rho = -w x F. With |w| = 1/radius
      // the centre moves at 1 m/s; the sign makes it move from view1 to view5.
      const double radius = arc_fixation_factor * scene.median_depth;
      path.fixation_point = midpoint + radius * Eigen::Vector3d::UnitZ();
      const Eigen::Vector3d w = -Eigen::Vector3d::UnitY() / radius;
      path.unit_twist.head<3>() = -w.cross(path.fixation_point);
      path.unit_twist.tail<3>() = w;
      break;
    }
    case CameraPathType::kRotate: {
      // Mostly yaw (about y) with some pitch, about the camera centre c:
      // rho = c x w keeps c fixed. |w| = 1 rad/s.
      const Eigen::Vector3d w = Eigen::Vector3d(0.3, 1.0, 0.0).normalized();
      path.unit_twist.head<3>() = midpoint.cross(w);
      path.unit_twist.tail<3>() = w;
      break;
    }
    case CameraPathType::kHandheld:
      // Drifts along the baseline like the lateral path (inside what the two
      // views cover), with seeded shake on top (see MakeHandheldShape).
      path.unit_twist.head<3>() = baseline_direction;
      path.handheld = MakeHandheldShape(duration, scene.median_depth, baseline_direction, seed);
      break;
  }
  return path;
}

MotionStats MeasureImageMotion(const PinholeCamera& camera, const cv::Mat& depth_end,
                               const SE3& T_world_start, const SE3& T_world_end) {
  const SE3 T_start_end = T_world_start.Inverse() * T_world_end;
  std::vector<float> motion;
  motion.reserve(depth_end.total());
  for (int y = 0; y < depth_end.rows; ++y) {
    const float* row = depth_end.ptr<float>(y);
    for (int x = 0; x < depth_end.cols; ++x) {
      if (!(row[x] > 0.0f) || !std::isfinite(row[x])) continue;
      const Eigen::Vector3d p_start = T_start_end * (row[x] * camera.Ray(x, y));
      if (p_start.z() <= kNearPlaneM) continue;
      motion.push_back(static_cast<float>((camera.Project(p_start) - Eigen::Vector2d(x, y)).norm()));
    }
  }
  MotionStats stats;
  stats.num_pixels = static_cast<int>(motion.size());
  if (motion.empty()) return stats;
  stats.min_px = *std::min_element(motion.begin(), motion.end());
  stats.max_px = *std::max_element(motion.begin(), motion.end());
  stats.median_px = Median(&motion);
  return stats;
}

// ------------------------------------------------------------- synthesis

void SynthesisOptions::Check() const {
  CheckInRange("--frames", num_frames, 2, 100000);
  CheckInRange("--scale", scale, 1, 8);
  CheckAbove("--exposure-ratio", exposure_ratio, 0.0);
  CheckInRange("--exposure-ratio", exposure_ratio, 0.0, 1.0);
  CheckInRange("--noise", noise_sigma, 0.0, 255.0);
  CheckAbove("--blur-px", blur_px, 0.0);
  CheckInRange("--blur-px", blur_px, 0.0, 500.0);
  // The estimator averages M = 50 samples per exposure; the data must be finer.
  CheckInRange("--subframes", subframes, 51, 100000);
  CheckAbove("--fps", fps, 0.0);
  CheckInRange("--fps", fps, 0.0, 10000.0);
  CheckAtLeast("--hr-width", hr_width, 0);
  CheckAtLeast("--hr-height", hr_height, 0);
  if ((hr_width == 0) != (hr_height == 0)) {
    throw InputError("--hr-width and --hr-height must both be positive or both 0 (automatic)");
  }
  if (hr_width % scale != 0 || hr_height % scale != 0) {
    throw InputError("--hr-width and --hr-height (" + std::to_string(hr_width) + "x" +
                     std::to_string(hr_height) + ") must be divisible by --scale " + std::to_string(scale));
  }
  CheckInRange("--arc-fixation", arc_fixation_factor, 1.2, 100.0);
  CheckInInterval("--forward-cap", forward_travel_cap, 0.0, 1.0, Interval::kRightClosed);
  CheckInInterval("max_hole_fraction", max_hole_fraction, 0.0, 1.0, Interval::kOpen);
  CheckInRange("--gain-jitter", gain_jitter, 0.0, 0.5);
  CheckInRange("--readout-ratio", readout_ratio, 0.0, 1.0);
}

double FrameStamp(const SynthesisOptions& options, int index) {
  return (index + 1) / options.fps;
}

double FrameExposure(const SynthesisOptions& options) {
  return options.exposure_ratio / options.fps;
}

double ReadoutTime(const SynthesisOptions& options) {
  return options.readout_ratio / options.fps;
}

namespace {

// Range of the camera centre's z over the rendered span of a hand-held path
// per unit speed (m per m/s), sampled finely against its low frequencies.
double HandheldDepthTravel(const CameraPath& path, const SynthesisOptions& options) {
  CameraPath unit = path;
  unit.speed = 1.0;
  const double t0 = PathStart(options), t1 = RenderedEnd(options);
  double low = std::numeric_limits<double>::infinity(), high = -low;
  constexpr int kSamples = 257;
  for (int k = 0; k < kSamples; ++k) {
    const double z = unit.PoseAt(t0 + (t1 - t0) * k / (kSamples - 1)).translation().z();
    low = std::min(low, z);
    high = std::max(high, z);
  }
  return std::max(high - low, 1e-9);
}

}  // namespace

double CalibratePathSpeed(const StereoScene& scene, const SceneRenderer& renderer,
                          const PinholeCamera& camera, const SynthesisOptions& options, CameraPath* path,
                          bool* capped) {
  // The middle frame; the hand-held path, whose speed varies, measures the
  // median over all frames of each frame's median.
  std::vector<int> frames = {(options.num_frames - 1) / 2};
  if (path->type == CameraPathType::kHandheld) {
    frames.resize(options.num_frames);
    for (int i = 0; i < options.num_frames; ++i) frames[i] = i;
  }
  RenderOptions render_options;
  render_options.fill_holes = false;
  RenderWorkspace workspace;
  RenderResult render;
  auto measure = [&](double speed) {
    path->speed = speed;
    std::vector<double> medians;
    for (int frame : frames) {
      const double t_close = FrameStamp(options, frame);
      const double t_open = t_close - FrameExposure(options);
      renderer.Render(camera, path->PoseAt(t_close), render_options, &workspace, &render);
      medians.push_back(
          MeasureImageMotion(camera, CoveredDepth(render), path->PoseAt(t_open), path->PoseAt(t_close))
              .median_px);
    }
    std::nth_element(medians.begin(), medians.begin() + medians.size() / 2, medians.end());
    return medians[medians.size() / 2];
  };

  // Forward (and hand-held) motion must stop well before the nearest surface.
  double max_speed = std::numeric_limits<double>::infinity();
  if (path->type == CameraPathType::kForward) {
    const double duration = RenderedEnd(options) - PathStart(options);
    max_speed = options.forward_travel_cap * scene.min_depth / (path->unit_twist.z() * duration);
  } else if (path->type == CameraPathType::kHandheld) {
    max_speed = options.forward_travel_cap * scene.min_depth / HandheldDepthTravel(*path, options);
  }
  *capped = false;
  // Lateral estimate (exact for a fronto-parallel plane at the median depth;
  // rotate: at the image centre), then fixed-point steps: image motion is
  // nearly proportional to speed.
  const double first_guess =
      path->type == CameraPathType::kRotate
          ? options.blur_px / (scene.focal_px * FrameExposure(options))
          : options.blur_px * scene.median_depth / (scene.focal_px * FrameExposure(options));
  double speed = path->speed > 0.0 ? path->speed : first_guess;
  double achieved = 0.0;
  for (int iteration = 0; iteration < 10; ++iteration) {
    if (speed >= max_speed) {
      speed = max_speed;
      *capped = true;
    }
    achieved = measure(speed);
    if (*capped || achieved <= 0.0) break;
    if (std::abs(achieved - options.blur_px) < 1e-3 * options.blur_px) break;
    speed *= options.blur_px / achieved;
  }
  path->speed = speed;
  return achieved;
}

namespace {

// Pixels of the w x h rectangle at (x, y) in the image of `integral`.
int CountInRect(const cv::Mat& integral, int x, int y, int w, int h) {
  return integral.at<int>(y + h, x + w) - integral.at<int>(y, x + w) - integral.at<int>(y + h, x) +
         integral.at<int>(y, x);
}

// Integral images of the uncovered pixels of the full-size probe at poses
// spread over the whole path (exposure of the first frame to the close of the
// last).
std::vector<cv::Mat> HoleIntegralsAlongPath(const SceneRenderer& renderer, const PinholeCamera& probe,
                                            const CameraPath& path, const SynthesisOptions& options) {
  const int num_poses = std::max(5, 2 * options.num_frames + 1);
  const double t0 = PathStart(options), t1 = RenderedEnd(options);
  std::vector<cv::Mat> hole_integrals(num_poses);
  RenderOptions render_options;
  render_options.fill_holes = false;
  RenderWorkspace workspace;
  RenderResult render;
  cv::Mat holes01;
  for (int k = 0; k < num_poses; ++k) {
    const double t = t0 + (t1 - t0) * k / (num_poses - 1);
    renderer.Render(probe, path.PoseAt(t), render_options, &workspace, &render);
    cv::threshold(render.hole_mask, holes01, 0, 1, cv::THRESH_BINARY);
    cv::integral(holes01, hole_integrals[k], CV_32S);
  }
  return hole_integrals;
}

// Holes inside the scene (unknown disparity in both views, disocclusions
// seen by neither) cannot be cropped away: their level is the worst hole
// fraction of the central quarter of the width x height image.
double InteriorHoleFraction(const std::vector<cv::Mat>& hole_integrals, int width, int height) {
  double interior = 0.0;
  for (const cv::Mat& integral : hole_integrals) {
    interior = std::max(interior, CountInRect(integral, width / 4, height / 4, width / 2, height / 2) /
                                      (static_cast<double>(width / 2) * (height / 2)));
  }
  return interior;
}

// Width of the band along a crop's edges that must run through covered pixels.
constexpr int kCropBand = 3;

// The worst hole fractions over the poses of the crop (x, y, w, h) and of
// its edge band.
void CropHoleFractions(const std::vector<cv::Mat>& hole_integrals, int x, int y, int w, int h, double* worst,
                       double* worst_band) {
  *worst = 0.0;
  *worst_band = 0.0;
  for (const cv::Mat& integral : hole_integrals) {
    const int all = CountInRect(integral, x, y, w, h);
    const int inner =
        CountInRect(integral, x + kCropBand, y + kCropBand, w - 2 * kCropBand, h - 2 * kCropBand);
    const double band_area = static_cast<double>(w) * h - (w - 2.0 * kCropBand) * (h - 2.0 * kCropBand);
    *worst = std::max(*worst, static_cast<double>(all) / (static_cast<double>(w) * h));
    *worst_band = std::max(*worst_band, (all - inner) / band_area);
  }
}

// Largest centred crop of the width x height image (divisible by the scale,
// at least half its size) whose worst pose leaves at most `max_holes` and
// whose edges run through covered pixels: the views' fields of view end at
// the crop's outside. When none does (the path leaves the views' coverage),
// the crop with the fewest holes.
cv::Size LargestCoveredCrop(const std::vector<cv::Mat>& hole_integrals, int width, int height, int s,
                            double max_holes) {
  constexpr double kMaxBandHoleFraction = 0.05;
  int best_w = 0, best_h = 0;
  double best_area = -1.0;
  int fallback_w = 0, fallback_h = 0;
  double fallback_holes = 2.0;
  const int min_w = std::max(2 * kCropBand + s, ((width / 2 + s - 1) / s) * s);
  const int min_h = std::max(2 * kCropBand + s, ((height / 2 + s - 1) / s) * s);
  for (int w = (width / s) * s; w >= min_w; w -= s) {
    for (int h = (height / s) * s; h >= min_h; h -= s) {
      if (static_cast<double>(w) * h <= best_area) break;  // smaller h only shrinks the area
      double worst = 0.0, worst_band = 0.0;
      CropHoleFractions(hole_integrals, (width - w) / 2, (height - h) / 2, w, h, &worst, &worst_band);
      if (worst <= max_holes && worst_band <= kMaxBandHoleFraction) {
        best_area = static_cast<double>(w) * h;
        best_w = w;
        best_h = h;
      } else if (worst < fallback_holes - 1e-9) {
        fallback_holes = worst;
        fallback_w = w;
        fallback_h = h;
      }
    }
  }
  if (best_w == 0) return cv::Size(fallback_w, fallback_h);
  return cv::Size(best_w, best_h);
}

}  // namespace

PinholeCamera ChooseHrCamera(const StereoScene& scene, const SceneRenderer& renderer, const CameraPath& path,
                             const SynthesisOptions& options) {
  const PinholeCamera probe = ProbeCamera(scene);
  const int width = probe.width, height = probe.height;
  if (options.hr_width > 0) {
    if (options.hr_width > width || options.hr_height > height) {
      throw InputError("--hr-width/--hr-height " + std::to_string(options.hr_width) + "x" +
                       std::to_string(options.hr_height) + " exceed the scene size " + std::to_string(width) +
                       "x" + std::to_string(height));
    }
    return CentredCrop(probe, options.hr_width, options.hr_height);
  }
  const std::vector<cv::Mat> hole_integrals = HoleIntegralsAlongPath(renderer, probe, path, options);
  // The interior holes are allowed on top of max_hole_fraction.
  const double max_holes = options.max_hole_fraction + InteriorHoleFraction(hole_integrals, width, height);
  const cv::Size crop = LargestCoveredCrop(hole_integrals, width, height, options.scale, max_holes);
  return CentredCrop(probe, crop.width, crop.height);
}

namespace {

// The blurred HR image of one exposure from many sub-frame renders.
// Sub-frames are summed in a fixed number of chunks, each in a fixed order,
// and the chunks in a fixed order: the result does not depend on threads.
class ExposureAverager {
 public:
  ExposureAverager(const PinholeCamera& hr, int num_subframes)
      : hr_(hr),
        num_subframes_(num_subframes),
        num_chunks_(std::min(num_subframes, 16)),
        num_threads_(std::max(1, omp_get_max_threads())),
        chunk_sums_(num_chunks_),
        chunk_max_holes_(num_chunks_),
        workspaces_(num_threads_),
        renders_(num_threads_) {
    for (cv::Mat& sum : chunk_sums_) sum.create(hr.height, hr.width, CV_32FC3);
  }

  // Buffers for renders outside Average, on the calling thread.
  RenderWorkspace* workspace() { return &workspaces_[0]; }

  // Rolling shutter (docs/file_formats.md#rolling-shutter): LR row y (of H) is exposed over
  // [t_o + y r / H, t_c + y r / H], r = readout, and so are the `scale` HR
  // rows that box-downsample into it. Sub-frames on the global shutter's grid
  // tau_j = t_o + (j / S) e, j = 1, 2, ..., over [t_o, t_c + r]; each row
  // averages the S of them inside its window (j in first(y) .. first(y) + S - 1),
  // so every row has the global shutter's sampling, and row 0 its very times.
  // readout 0 is the global shutter, eq:blurOperator's mean over
  // tau_m = t_o + (m / S)(t_c - t_o), m = 1..S. Writes `blurred` (CV_32FC3,
  // HR size); returns the most holes of a sub-frame.
  int Average(const SceneRenderer& renderer, const CameraPath& path, double t_open, double exposure,
              double readout, int scale, const RenderOptions& render_options, cv::Mat* blurred) {
    const int num_rows = hr_.height / scale;
    std::vector<int> first(num_rows);
    for (int y = 0; y < num_rows; ++y) {
      first[y] = 1 + static_cast<int>(std::floor(y * readout / num_rows * num_subframes_ / exposure));
    }
    const int num_renders = first.back() + num_subframes_ - 1;
#pragma omp parallel for schedule(dynamic, 1) num_threads(num_threads_)
    for (int c = 0; c < num_chunks_; ++c) {
      const int thread = omp_get_thread_num();
      RenderResult& render = renders_[thread];
      chunk_sums_[c].setTo(cv::Scalar::all(0.0));
      chunk_max_holes_[c] = 0;
      const int j_begin = 1 + static_cast<int>(static_cast<long>(c) * num_renders / num_chunks_);
      const int j_end = static_cast<int>(static_cast<long>(c + 1) * num_renders / num_chunks_);
      for (int j = j_begin; j <= j_end; ++j) {
        const double tau = t_open + (static_cast<double>(j) / num_subframes_) * exposure;
        renderer.Render(hr_, path.PoseAt(tau), render_options, &workspaces_[thread], &render);
        if (readout == 0.0) {  // every row shares the window: one add
          cv::add(chunk_sums_[c], render.image, chunk_sums_[c]);
        }
        for (int y = 0; y < num_rows && readout != 0.0; ++y) {
          if (j < first[y] || j >= first[y] + num_subframes_) continue;
          const cv::Range rows(y * scale, (y + 1) * scale);
          cv::Mat sum_rows = chunk_sums_[c].rowRange(rows);
          cv::add(sum_rows, render.image.rowRange(rows), sum_rows);
        }
        chunk_max_holes_[c] = std::max(chunk_max_holes_[c], render.num_holes);
      }
    }
    blurred->create(hr_.height, hr_.width, CV_32FC3);
    blurred->setTo(cv::Scalar::all(0.0));
    for (int c = 0; c < num_chunks_; ++c) cv::add(*blurred, chunk_sums_[c], *blurred);
    *blurred *= 1.0 / num_subframes_;
    return *std::max_element(chunk_max_holes_.begin(), chunk_max_holes_.end());
  }

 private:
  PinholeCamera hr_;
  int num_subframes_;
  int num_chunks_;
  int num_threads_;
  std::vector<cv::Mat> chunk_sums_;
  std::vector<int> chunk_max_holes_;
  std::vector<RenderWorkspace> workspaces_;
  std::vector<RenderResult> renders_;
};

// The 8-bit LR frame of a blurred HR image: box-downsampled by the scale
// (INTER_AREA with an integer factor is the box average), then noise from `rng`.
cv::Mat LowResImage(const cv::Mat& blurred, const SynthesisOptions& options, cv::RNG* rng) {
  cv::Mat low_res;
  if (options.scale == 1) {
    blurred.copyTo(low_res);
  } else {
    cv::resize(blurred, low_res, cv::Size(blurred.cols / options.scale, blurred.rows / options.scale), 0.0,
               0.0, cv::INTER_AREA);
  }
  if (options.noise_sigma > 0.0) {
    cv::Mat noise(low_res.size(), low_res.type());
    rng->fill(noise, cv::RNG::NORMAL, 0.0, options.noise_sigma);
    low_res += noise;
  }
  cv::Mat image8;
  low_res.convertTo(image8, CV_8UC3);  // rounds and saturates to 0..255
  return image8;
}

// The path's speed and the cameras: speed first on the full-size camera, then
// the crop that stays covered along that path, then the speed again on the
// final crop.
void PlanPathAndCameras(const StereoScene& scene, const SceneRenderer& renderer,
                        const SynthesisOptions& options, SynthesisResult* result, std::ostream* log) {
  const double t_mid = 0.5 * (PathStart(options) + PathEnd(options));
  result->path = MakeCameraPath(options.path, scene, t_mid, options.arc_fixation_factor,
                                PathEnd(options) - PathStart(options), options.seed);
  CalibratePathSpeed(scene, renderer, ProbeCamera(scene), options, &result->path, &result->speed_capped);
  result->hr_camera = ChooseHrCamera(scene, renderer, result->path, options);
  result->achieved_blur_px =
      CalibratePathSpeed(scene, renderer, result->hr_camera, options, &result->path, &result->speed_capped);
  result->lr_camera = options.scale == 1 ? result->hr_camera : result->hr_camera.Downscaled(options.scale);
  if (log && result->speed_capped) {
    *log << "note: the " << CameraPathName(options.path) << " path is capped at "
         << options.forward_travel_cap << " x the nearest depth; median blur " << result->achieved_blur_px
         << " px instead of " << options.blur_px << " px\n";
  }
}

// The sequence's calibrations (LR and gt HR), named after the scene folder:
// "scenes/Dolls/" names the scene "Dolls".
void NameCalibrations(const StereoScene& scene, SynthesisResult* result) {
  fs::path folder = fs::path(scene.folder).lexically_normal();
  if (folder.filename().empty()) folder = folder.parent_path();
  const std::string scene_name = folder.filename().string();
  Sequence& sequence = result->sequence;
  sequence.calibration = CameraCalibration::FromCamera(result->lr_camera, "synthetic_" + scene_name);
  sequence.ground_truth.emplace();
  sequence.ground_truth->calibration =
      CameraCalibration::FromCamera(result->hr_camera, "synthetic_" + scene_name + "_hr");
}

void LogFrame(int i, const SynthesisOptions& options, const FrameSynthesisStats& stats, std::ostream* log) {
  if (!log) return;
  std::ostringstream line;
  line << "frame " << i + 1 << "/" << options.num_frames << ": blur median " << std::fixed
       << std::setprecision(1) << stats.blur.median_px << " px (max " << stats.blur.max_px << "), holes "
       << std::setprecision(2) << 100.0 * stats.hole_fraction_max << " %\n";
  *log << line.str() << std::flush;
}

// Frame i: the ground truth at the shutter close time t_c, the blurred
// exposure and its LR image, appended to the result.
void SynthesizeFrame(int i, const SceneRenderer& renderer, const SynthesisOptions& options, double gain,
                     ExposureAverager* averager, cv::RNG* rng, SynthesisResult* result) {
  const PinholeCamera& hr = result->hr_camera;
  const double exposure = FrameExposure(options);
  const double readout = ReadoutTime(options);
  const double t_close = FrameStamp(options, i);
  const double t_open = t_close - exposure;
  const CameraPath& path = result->path;
  const SE3 T_world_close = path.PoseAt(t_close);
  // Only the points this exposure can see: same images, faster renders.
  std::vector<SE3> exposure_poses = {path.PoseAt(t_open), path.PoseAt(0.5 * (t_open + t_close)),
                                     T_world_close};
  if (readout > 0.0) exposure_poses.push_back(path.PoseAt(t_close + readout));  // the bottom row's close
  const SceneRenderer frame_renderer = renderer.CulledFor(hr, exposure_poses);

  // One primary view for the whole exposure and its ground truth, the one
  // nearer to the camera at the shutter close. Chosen per sub-frame, the
  // exposure that the path crosses the views' bisector in (one frame of most
  // hand-held clips) blended renders of both views, which differ slightly in
  // colour and geometry: a blur that no single latent image explains (39-48
  // dB of model agreement from the ground truth there, against 47-53 dB for
  // the other interior frames; BENCHMARKS.md "One primary view per
  // exposure").
  RenderOptions render_options;
  render_options.primary_view = renderer.PrimaryView(T_world_close);
  RenderResult sharp;
  frame_renderer.Render(hr, T_world_close, render_options, averager->workspace(), &sharp);
  FrameSynthesisStats stats;
  stats.hole_fraction_latent = sharp.HoleFraction();
  stats.blur = MeasureImageMotion(hr, CoveredDepth(sharp), path.PoseAt(t_open), T_world_close);

  cv::Mat blurred;
  const int max_holes = averager->Average(frame_renderer, path, t_open, exposure, readout, options.scale,
                                          render_options, &blurred);
  stats.hole_fraction_max = static_cast<double>(max_holes) / hr.NumPixels();
  stats.gain = gain;
  if (gain != 1.0) {
    blurred *= gain;
    sharp.image *= gain;
  }
  cv::Mat latent8;
  sharp.image.convertTo(latent8, CV_8UC3);  // rounds and clamps to 0..255

  Sequence& sequence = result->sequence;
  SequenceGroundTruth& gt = *sequence.ground_truth;
  sequence.frames.push_back({i, t_close, exposure});
  sequence.images.push_back(LowResImage(blurred, options, rng));
  gt.latent.push_back(latent8);
  gt.depth.push_back(sharp.depth.clone());
  gt.poses.push_back({t_close, T_world_close});
  result->frame_stats.push_back(stats);
}

// Per frame a gain from [1 - G, 1 + G], from its own stream of the seed
// (the noise keeps cv::RNG(seed)); all 1 for G = 0.
std::vector<double> FrameGains(const SynthesisOptions& options) {
  std::vector<double> gains(options.num_frames, 1.0);
  if (options.gain_jitter <= 0.0) return gains;
  SeededUniform uniform(options.seed ^ kGainStream);
  for (double& gain : gains) gain = uniform.Next(1.0 - options.gain_jitter, 1.0 + options.gain_jitter);
  return gains;
}

}  // namespace

SynthesisResult SynthesizeSequence(const StereoScene& scene, const SynthesisOptions& options,
                                   std::ostream* log) {
  options.Check();
  const auto start_time = std::chrono::steady_clock::now();
  SynthesisResult result;
  const SceneRenderer renderer(scene);
  PlanPathAndCameras(scene, renderer, options, &result, log);
  NameCalibrations(scene, &result);
  ExposureAverager averager(result.hr_camera, options.subframes);
  result.sequence.readout_time = ReadoutTime(options);
  cv::RNG rng(options.seed);
  const std::vector<double> gains = FrameGains(options);
  for (int i = 0; i < options.num_frames; ++i) {
    SynthesizeFrame(i, renderer, options, gains[i], &averager, &rng, &result);
    LogFrame(i, options, result.frame_stats.back(), log);
  }
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_time).count();
  return result;
}

namespace {

void EmitCamera(YAML::Emitter* out, const char* key, const PinholeCamera& camera) {
  *out << YAML::Key << key << YAML::Value << YAML::BeginMap;
  *out << YAML::Key << "width" << YAML::Value << camera.width;
  *out << YAML::Key << "height" << YAML::Value << camera.height;
  *out << YAML::Key << "fx" << YAML::Value << camera.fx;
  *out << YAML::Key << "fy" << YAML::Value << camera.fy;
  *out << YAML::Key << "cx" << YAML::Value << camera.cx;
  *out << YAML::Key << "cy" << YAML::Value << camera.cy;
  *out << YAML::EndMap;
}

// A flow list [a, b, ...] of the values of an Eigen vector.
template <typename Vector>
void EmitList(YAML::Emitter* out, const Vector& v) {
  *out << YAML::Flow << YAML::BeginSeq;
  for (int i = 0; i < v.size(); ++i) *out << v[i];
  *out << YAML::EndSeq;
}

void EmitSceneCalibration(YAML::Emitter* out, const StereoScene& scene) {
  *out << YAML::Key << "scene_calibration" << YAML::Value << YAML::BeginMap;
  *out << YAML::Key << "focal_px" << YAML::Value << scene.focal_px;
  *out << YAML::Key << "baseline_m" << YAML::Value << scene.baseline_m;
  *out << YAML::Key << "dmin" << YAML::Value << scene.dmin;
  *out << YAML::Key << "view5_cx_offset_px" << YAML::Value
       << scene.views[1].camera.cx - scene.views[0].camera.cx;
  *out << YAML::Key << "depth_min_m" << YAML::Value << scene.min_depth;
  *out << YAML::Key << "depth_median_m" << YAML::Value << scene.median_depth;
  *out << YAML::Key << "depth_max_m" << YAML::Value << scene.max_depth;
  *out << YAML::EndMap;
}

void EmitOptions(YAML::Emitter* out, const SynthesisOptions& options) {
  *out << YAML::Key << "options" << YAML::Value << YAML::BeginMap;
  *out << YAML::Key << "frames" << YAML::Value << options.num_frames;
  *out << YAML::Key << "scale" << YAML::Value << options.scale;
  *out << YAML::Key << "exposure_ratio" << YAML::Value << options.exposure_ratio;
  *out << YAML::Key << "path" << YAML::Value << CameraPathName(options.path);
  *out << YAML::Key << "noise" << YAML::Value << options.noise_sigma;
  *out << YAML::Key << "seed" << YAML::Value << options.seed;
  *out << YAML::Key << "blur_px" << YAML::Value << options.blur_px;
  *out << YAML::Key << "subframes" << YAML::Value << options.subframes;
  *out << YAML::Key << "fps" << YAML::Value << options.fps;
  *out << YAML::Key << "hr_width" << YAML::Value << options.hr_width;
  *out << YAML::Key << "hr_height" << YAML::Value << options.hr_height;
  *out << YAML::Key << "arc_fixation_factor" << YAML::Value << options.arc_fixation_factor;
  *out << YAML::Key << "forward_travel_cap" << YAML::Value << options.forward_travel_cap;
  *out << YAML::Key << "max_hole_fraction" << YAML::Value << options.max_hole_fraction;
  *out << YAML::Key << "gain_jitter" << YAML::Value << options.gain_jitter;
  *out << YAML::Key << "readout_ratio" << YAML::Value << options.readout_ratio;
  *out << YAML::Key << "readout_time" << YAML::Value << ReadoutTime(options) << YAML::Comment("s");
  *out << YAML::EndMap;
}

// Per axis [amplitude, cycles, phase] of each sinusoid (see CameraPath).
void EmitSinusoids(YAML::Emitter* out, const char* key,
                   const std::array<std::vector<PathSinusoid>, 3>& axes) {
  *out << YAML::Key << key << YAML::Value << YAML::BeginSeq;
  for (const std::vector<PathSinusoid>& terms : axes) {
    *out << YAML::Flow << YAML::BeginSeq;
    for (const PathSinusoid& term : terms) {
      EmitList(out, Eigen::Vector3d(term.amplitude, term.cycles, term.phase));
    }
    *out << YAML::EndSeq;
  }
  *out << YAML::EndSeq;
}

void EmitHandheldShape(YAML::Emitter* out, const HandheldShape& shape) {
  *out << YAML::Key << "handheld" << YAML::Value
       << YAML::Comment(
              "centre = T_world_mid.t + speed * ((t - t_mid) * twist.rho + translation(u)), R = "
              "Exp(speed * rotation(u)), u = (t - t_mid) / duration; per axis x, y, z a sum of "
              "amplitude * sin(2 pi cycles u + phase), listed as [amplitude, cycles, phase]")
       << YAML::BeginMap;
  *out << YAML::Key << "duration" << YAML::Value << shape.duration;
  EmitSinusoids(out, "translation", shape.translation);
  EmitSinusoids(out, "rotation", shape.rotation);
  *out << YAML::EndMap;
}

void EmitPath(YAML::Emitter* out, const SynthesisOptions& options, const SynthesisResult& result) {
  const CameraPath& p = result.path;
  const Eigen::Quaterniond q = p.T_world_mid.quaternion();
  *out << YAML::Key << "path" << YAML::Value
       << YAML::Comment("T_world_cam(t) = Exp((t - t_mid) * twist_per_s) * T_world_mid, twist = (rho, phi)")
       << YAML::BeginMap;
  *out << YAML::Key << "type" << YAML::Value << CameraPathName(p.type);
  *out << YAML::Key << "t_mid" << YAML::Value << p.t_mid;
  *out << YAML::Key << "T_world_mid" << YAML::Value;
  EmitList(out, p.T_world_mid.translation());
  *out << YAML::Comment("tx ty tz");
  *out << YAML::Key << "T_world_mid_quaternion" << YAML::Value;
  EmitList(out, Eigen::Vector4d(q.x(), q.y(), q.z(), q.w()));
  *out << YAML::Comment("qx qy qz qw");
  *out << YAML::Key << "twist_per_s" << YAML::Value;
  EmitList(out, p.Twist());
  if (p.type == CameraPathType::kRotate) {
    *out << YAML::Key << "angular_speed_radps" << YAML::Value << p.speed;
  } else {
    *out << YAML::Key << "centre_speed_mps" << YAML::Value << p.speed;
  }
  if (p.type == CameraPathType::kArc) {
    *out << YAML::Key << "fixation_point" << YAML::Value;
    EmitList(out, p.fixation_point);
  }
  if (p.type == CameraPathType::kHandheld) EmitHandheldShape(out, p.handheld);
  *out << YAML::Key << "speed_capped" << YAML::Value << result.speed_capped;
  *out << YAML::Key << "target_blur_px" << YAML::Value << options.blur_px;
  *out << YAML::Key << "achieved_blur_px" << YAML::Value << result.achieved_blur_px
       << YAML::Comment(p.type == CameraPathType::kHandheld ? "median over the frames of their medians"
                                                            : "median, middle frame");
  *out << YAML::EndMap;
}

void EmitFrames(YAML::Emitter* out, const SynthesisResult& result) {
  *out << YAML::Key << "frames" << YAML::Value
       << YAML::Comment("blur = image motion over the exposure in HR px, over covered pixels")
       << YAML::BeginSeq;
  for (std::size_t i = 0; i < result.frame_stats.size(); ++i) {
    const FrameSynthesisStats& s = result.frame_stats[i];
    const FrameRecord& f = result.sequence.frames[i];
    *out << YAML::Flow << YAML::BeginMap;
    *out << YAML::Key << "index" << YAML::Value << f.index;
    *out << YAML::Key << "stamp" << YAML::Value << f.stamp;
    *out << YAML::Key << "exposure" << YAML::Value << f.exposure;
    *out << YAML::Key << "blur_min_px" << YAML::Value << s.blur.min_px;
    *out << YAML::Key << "blur_median_px" << YAML::Value << s.blur.median_px;
    *out << YAML::Key << "blur_max_px" << YAML::Value << s.blur.max_px;
    *out << YAML::Key << "hole_fraction_latent" << YAML::Value << s.hole_fraction_latent;
    *out << YAML::Key << "hole_fraction_max_subframe" << YAML::Value << s.hole_fraction_max;
    *out << YAML::Key << "gain" << YAML::Value << s.gain;
    *out << YAML::EndMap;
  }
  *out << YAML::EndSeq;
}

}  // namespace

void WriteSynthesisYaml(const std::string& path, const StereoScene& scene, const SynthesisOptions& options,
                        const SynthesisResult& result) {
  YAML::Emitter out;
  out.SetDoublePrecision(10);
  out << YAML::Comment(
      "synthesize_sequence: how this sequence was made (extra file, not read by the\n"
      "estimator). World frame = the view1 camera of the scene (optical frame).");
  out << YAML::BeginMap;
  out << YAML::Key << "scene" << YAML::Value << scene.folder;
  EmitSceneCalibration(&out, scene);
  EmitOptions(&out, options);
  EmitCamera(&out, "hr_camera", result.hr_camera);
  EmitCamera(&out, "lr_camera", result.lr_camera);
  EmitPath(&out, options, result);
  EmitFrames(&out, result);
  out << YAML::Key << "seconds" << YAML::Value << result.seconds;
  out << YAML::EndMap;
  if (!out.good()) throw InputError(path + ": cannot format the YAML (" + out.GetLastError() + ")");

  std::error_code error;
  fs::create_directories(fs::path(path).parent_path(), error);
  std::ofstream file(path);
  if (!file) throw InputError(path + ": cannot write the file");
  file << out.c_str() << "\n";
  if (!file) throw InputError(path + ": cannot write the file");
}

}  // namespace deblur_sr_mvs
