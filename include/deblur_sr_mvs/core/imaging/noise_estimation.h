// Sensor-noise level of the input frames: the standard deviation of additive
// white noise, estimated from the images themselves (no noise-free reference).
#pragma once

#include <vector>

#include <opencv2/core.hpp>

namespace deblur_sr_mvs {

// Standard deviation of additive white Gaussian noise in `image` (float,
// 1 or 3 channels, any scale: the result has the image's units).
//
// Immerkaer's operator (Immerkaer 1996, "Fast noise variance estimation"):
// the 3x3 mask [1 -2 1; -2 4 -2; 1 -2 1], the difference of two discrete
// Laplacians, cancels intensity up to second order (planes and ramps), and
// white noise of sigma comes out with standard deviation 6 sigma. Where the
// scene leaks through (edges, texture) the response is larger, so instead of
// Immerkaer's mean of |response| this takes a low `quantile` of it over the
// interior pixels of every channel, divided by that quantile of |6 x| for
// x ~ N(0, 1): blurred frames have little scene above the second order, and
// a low quantile ignores what there is. `quantization_step`: the image's
// intensity step (1/255 for 8-bit frames scaled to [0, 1]); the response
// of a quantised image takes few values at low noise, and the quantile is
// interpolated between them.
//
// On blurred 8-bit frames (test/core/imaging/noise_estimation_test.cc) the
// estimate is within 10 % of the truth at sigma 2 and 4 gray levels; on
// noise-free frames it reads 0.6-0.8 (rounding and scene detail), which
// adds in quadrature at sigma 1 (+10 to +30 %).
double EstimateNoiseSigma(const cv::Mat& image, double quantization_step = 1.0 / 255.0,
                          double quantile = 0.25);

// One noise level for a window of frames from the same sensor: the median of
// the frames' EstimateNoiseSigma (0 for no frames).
double EstimateNoiseSigma(const std::vector<cv::Mat>& images, double quantization_step = 1.0 / 255.0,
                          double quantile = 0.25);

// The part of a noise estimate above the estimate's floor on noise-free
// frames (8-bit rounding, scene detail), the two adding in quadrature:
// sqrt(max(0, estimate^2 - floor^2)); a negative estimate reads as 0.
double NoiseAboveFloor(double estimated_noise, double floor);

}  // namespace deblur_sr_mvs
