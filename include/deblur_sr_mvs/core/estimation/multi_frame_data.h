// Multi-frame data pass (issue 12, "the image update must not amplify
// noise"; BENCHMARKS.md "Multi-frame evidence in the last image pass").
//
// In eq:imgUpdate the self-consistency term lambda_s |B_t - Psi_t I_t|
// (eq:IPterm, lambda_s 30) outweighs each matching term |B_s - Psi_s I_t|
// (weight 1) thirty to one, so the least-squares solution reproduces B_t's
// own noise draw and the deblurring amplifies it, although the neighbours
// B_s observe the same scene with independent noise. After the last image
// update, with the final depth and poses (so depth, poses and energies are
// not touched), this pass re-solves each I_t from its current value with the
// matching terms raised to `relative_weight` x lambda_s wherever the
// neighbour agrees with I_t (MultiFrameAgreementMask): the solution then
// averages the frames' noise instead of deconvolving one frame's noise. A
// neighbour pixel that disagrees (occlusion, mis-registration, a blur-model
// error) is left out of the pass. On by default (library, so the node too):
// +0.16 to +0.40 dB on lateral, arc and forward paths at sigma 0-4, -0.02
// to +0.27 dB hand-held, for 4-10 % of a run's time; the added noise falls by
// 0-10 % only (it is still 1.6-3.2x sigma at sigma 2).
#pragma once

#include <opencv2/core.hpp>

namespace deblur_sr_mvs {

struct MultiFrameDataOptions {
  // Weight of each agreeing neighbour pixel's matching term in the pass, as a
  // fraction of lambda_s (1: the neighbour counts as much as the frame
  // itself; 0.5 measured no better). 0: no pass (the output images of
  // before, bit for bit).
  double relative_weight = 1.0;
  // Neighbours of t taken: the frames within this distance (their capture
  // operators of Psi_s I_t; beyond EstimatorOptions::neighbour_radius they
  // are built for the pass).
  int radius = 1;
  // A neighbour's LR pixel agrees where the RMS of its residual Psi_s I_t -
  // B_s over a patch_px x patch_px patch (and the channels) is at most
  // agreement_scale x sqrt(model_error_sigma^2 + noise_sigma^2), the
  // residual expected from noise and model error (EstimatorOptions).
  double agreement_scale = 2.0;
  int patch_px = 5;  // odd
  // Leave window frame 0 out of the pass, as target and as raised neighbour
  // evidence: its blur path has no previous frame and is extrapolated from
  // frame 1 at constant velocity (MakeCaptureGeometry), wrong on paths whose
  // velocity changes (hand-held), so that its Psi_0 misfits (BENCHMARKS.md
  // "What limits hand-held Aloe"). A stream's continued window holds it anyway.
  bool skip_first_frame = true;
  // The pass's IRLS reweightings and CG steps per reweighting.
  int irls_iterations = 2;
  int cg_iterations = 13;
  void Check() const;  // throws InputError naming the bad value
};

// The LR mask (CV_8UC1, 255 = agrees) of the pixels where `predicted` (Psi_s
// I_t) matches `observation` (B_s): the patch mean (patch_px, reflected
// border) of the channel-mean squared difference at most threshold^2, and
// `visible` (CV_8UC1, non-zero; empty = all) there.
cv::Mat MultiFrameAgreementMask(const cv::Mat& predicted, const cv::Mat& observation, const cv::Mat& visible,
                                double threshold, int patch_px);

}  // namespace deblur_sr_mvs
