#include "deblur_sr_mvs/core/estimation/photometric.h"

#include <algorithm>

#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "deblur_sr_mvs/core/common/options_check.h"

namespace deblur_sr_mvs {
namespace {

// The frame as one float channel in [0, 1] and as 8 bit (for the tracker).
struct GrayFrame {
  cv::Mat gray;     // CV_32FC1
  cv::Mat gray8;    // CV_8UC1 (corners)
  cv::Mat detail8;  // CV_8UC1, 128 + the high-pass of gray (what KLT tracks)
  cv::Mat box;      // local means of gray
  cv::Mat clipped;  // CV_8UC1, non-zero within the box of a clipped pixel
};

GrayFrame ToGrayFrame(const cv::Mat& image, const GainEstimationOptions& options) {
  GrayFrame frame;
  cv::Mat brightest = image;
  if (image.channels() == 3) {
    std::vector<cv::Mat> channels;
    cv::split(image, channels);
    brightest = cv::max(cv::max(channels[0], channels[1]), channels[2]);
  }
  const int size = 2 * options.box_radius + 1;
  // A pixel clipped at white keeps its value when the gain rises: its ratio
  // would pull the median towards 1. The box of every such pixel is left out.
  cv::dilate(brightest >= options.max_intensity, frame.clipped,
             cv::getStructuringElement(cv::MORPH_RECT, cv::Size(size + 2, size + 2)));
  if (image.channels() == 3) {
    cv::Mat mean;
    cv::transform(image, mean, cv::Matx13f(1.0f / 3, 1.0f / 3, 1.0f / 3));
    frame.gray = mean;
  } else {
    frame.gray = image;
  }
  frame.gray.convertTo(frame.gray8, CV_8U, 255.0);
  // KLT assumes brightness constancy: under a gain it moves a corner towards
  // where b matches a's brightness, which pulls the ratio towards 1 (or
  // towards any guess b was divided by). A zero-mean high-pass scales with
  // the gain about 0, which shifts no SSD minimum: it is tracked instead.
  cv::Mat low;
  cv::GaussianBlur(frame.gray, low, cv::Size(0, 0), 2.0);
  cv::Mat detail = frame.gray - low;
  detail.convertTo(frame.detail8, CV_8U, 2.0 * 255.0, 128.0);
  cv::blur(frame.gray, frame.box, cv::Size(size, size), cv::Point(-1, -1), cv::BORDER_REPLICATE);
  return frame;
}

// The local mean at a sub-pixel position (bilinear). Rounding the tracked
// position instead misplaces the box by up to half a pixel where the image
// has its strongest gradients (corners): 1.1 % gain error over 8 frames of a
// pure rotation (no parallax, no brightness change), against 0.06 %.
float BoxAt(const cv::Mat& box, const cv::Point2f& p) {
  cv::Mat value;
  cv::getRectSubPix(box, cv::Size(1, 1), p, value);
  return value.at<float>(0, 0);
}

unsigned char ValueAt(const cv::Mat& mask, const cv::Point2f& p) {
  const int x = std::clamp(cvRound(p.x), 0, mask.cols - 1);
  const int y = std::clamp(cvRound(p.y), 0, mask.rows - 1);
  return mask.at<unsigned char>(y, x);
}

// Gain of b relative to a: the median of b's over a's local means at the
// corners of a that KLT finds in b (1 with too few of them).
double PairGain(const GrayFrame& a, const GrayFrame& b, const GainEstimationOptions& options) {
  std::vector<cv::Point2f> corners, tracked;
  cv::goodFeaturesToTrack(a.gray8, corners, options.max_corners, 0.01, 5.0);
  if (static_cast<int>(corners.size()) < options.min_matches) return 1.0;
  std::vector<unsigned char> status;
  std::vector<float> error;
  cv::calcOpticalFlowPyrLK(a.detail8, b.detail8, corners, tracked, status, error);
  // Forward-backward check: a track that does not lead back to its corner
  // (occlusion, a repeated texture, the blur of the other frame) gives no ratio.
  std::vector<cv::Point2f> back;
  std::vector<unsigned char> back_status;
  cv::calcOpticalFlowPyrLK(b.detail8, a.detail8, tracked, back, back_status, error);
  for (size_t i = 0; i < corners.size(); ++i) {
    if (!back_status[i] || cv::norm(back[i] - corners[i]) > options.max_track_error_px) status[i] = 0;
  }
  const float margin = static_cast<float>(options.box_radius);
  std::vector<double> ratios;
  ratios.reserve(corners.size());
  for (size_t i = 0; i < corners.size(); ++i) {
    const cv::Point2f& q = tracked[i];
    if (!status[i] || q.x < margin || q.y < margin || q.x > b.box.cols - 1 - margin ||
        q.y > b.box.rows - 1 - margin) {
      continue;
    }
    if (ValueAt(a.clipped, corners[i]) != 0 || ValueAt(b.clipped, q) != 0) continue;
    const double mean_a = BoxAt(a.box, corners[i]), mean_b = BoxAt(b.box, q);
    if (mean_a < options.min_intensity || mean_b < options.min_intensity) continue;
    ratios.push_back(mean_b / mean_a);
  }
  if (static_cast<int>(ratios.size()) < options.min_matches) return 1.0;
  const auto middle = ratios.begin() + ratios.size() / 2;
  std::nth_element(ratios.begin(), middle, ratios.end());
  return *middle;
}

}  // namespace

void GainEstimationOptions::Check() const {
  CheckInRange("gain max_corners", max_corners, 10, 10000);
  CheckInRange("gain box_radius", box_radius, 0, 10);
  CheckInRange("gain min_intensity", min_intensity, 0.0, 0.5);
  CheckInRange("gain max_intensity", max_intensity, 0.5, 1.0);
  CheckAtLeast("gain min_matches", min_matches, 3);
  CheckInRange("gain max_track_error_px", max_track_error_px, 0.0, 10.0);
}

std::vector<double> EstimateFrameGains(const std::vector<cv::Mat>& images,
                                       const GainEstimationOptions& options) {
  options.Check();
  std::vector<double> gains(images.size(), 1.0);
  if (images.empty()) return gains;
  GrayFrame previous = ToGrayFrame(images[0], options);
  for (size_t t = 1; t < images.size(); ++t) {
    GrayFrame current = ToGrayFrame(images[t], options);
    gains[t] = gains[t - 1] * PairGain(previous, current, options);
    previous = std::move(current);
  }
  return gains;
}

}  // namespace deblur_sr_mvs
