// Sequence and result folders exactly as docs/file_formats.md fixes them.
// Every reader validates its input and throws InputError with one line that
// names the file (and line, where there is one) and the problem.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "deblur_sr_mvs/core/common/errors.h"
#include "deblur_sr_mvs/core/geometry/camera.h"
#include "deblur_sr_mvs/core/geometry/frame_types.h"
#include "deblur_sr_mvs/core/geometry/se3.h"

namespace deblur_sr_mvs {

// camera_calibration YAML (image_width, image_height, camera_name,
// camera_matrix, distortion_model, distortion_coefficients,
// rectification_matrix, projection_matrix).
struct CameraCalibration {
  PinholeCamera camera;
  std::string camera_name = "camera";
  std::string distortion_model = "plumb_bob";
  std::vector<double> distortion = std::vector<double>(5, 0.0);
  Eigen::Matrix3d rectification = Eigen::Matrix3d::Identity();
  Eigen::Matrix<double, 3, 4> projection = Eigen::Matrix<double, 3, 4>::Zero();

  // Calibration of an undistorted camera; P = [K | 0].
  static CameraCalibration FromCamera(const PinholeCamera& camera, const std::string& name);
  bool HasDistortion() const;
};

// Optional ground truth (gt/), never read by the estimator.
struct SequenceGroundTruth {
  CameraCalibration calibration;   // intrinsics at the HR size
  std::vector<cv::Mat> latent;     // sharp HR images at t_c (8-bit, as stored)
  std::vector<cv::Mat> depth;      // CV_32FC1 depth in m along the optical axis; 0/NaN unknown
  std::vector<StampedPose> poses;  // T_world_cam at t_c
};

struct Sequence {
  CameraCalibration calibration;  // intrinsics of the input frames
  std::vector<FrameRecord> frames;
  std::vector<cv::Mat> images;  // CV_8UC1 or CV_8UC3 (OpenCV BGR order), one per frame
  // Rolling-shutter readout time (s) from the optional sensor.yaml; 0 (or no
  // file) = global shutter. frames.csv's stamp is then t_c of row 0, and LR row
  // y of H is exposed readout_time * y / H later (docs/file_formats.md).
  double readout_time = 0.0;
  std::optional<SequenceGroundTruth> ground_truth;
};

// Readers and writers of the single files. Writers create parent folders and
// throw InputError when a file cannot be written.
CameraCalibration ReadCameraYaml(const std::string& path);
void WriteCameraYaml(const std::string& path, const CameraCalibration& calibration);

// Validates: header, contiguous indices from 0, strictly increasing stamps,
// 0 < exposure <= frame interval (the gap to the previous stamp; for the first
// frame, the gap to the next one).
std::vector<FrameRecord> ReadFramesCsv(const std::string& path);
void WriteFramesCsv(const std::string& path, const std::vector<FrameRecord>& frames);

// sensor.yaml: one key, `readout_time: <seconds>`, a finite number >= 0 and
// at most the smallest frame interval of `frames` (the gap between
// consecutive stamps). Errors name file:line.
double ReadSensorYaml(const std::string& path, const std::vector<FrameRecord>& frames);
// ReadSensorYaml's check of a value, for other sources (a rosbag): the
// problem in words, "" when there is none.
std::string ReadoutTimeProblem(double readout_time, const std::vector<FrameRecord>& frames);
void WriteSensorYaml(const std::string& path, double readout_time);

// TUM format: `stamp tx ty tz qx qy qz qw` per line, '#' comments allowed.
std::vector<StampedPose> ReadTumTrajectory(const std::string& path);
void WriteTumTrajectory(const std::string& path, const std::vector<StampedPose>& poses);

// float32 single-channel TIFF.
cv::Mat ReadDepthTiff(const std::string& path);
void WriteDepthTiff(const std::string& path, const cv::Mat& depth);

// 8-bit gray or colour PNG; rejects other depths and channel counts.
cv::Mat ReadImage8(const std::string& path);
void WriteImage(const std::string& path, const cv::Mat& image);

// The whole content of a text file; InputError naming it when it is missing,
// a folder or unreadable.
std::string ReadTextFile(const std::string& path);

// "000042": the zero-padded file stem of frame `index`.
std::string FrameStem(int index);

// Whole sequence folder. Checks that every frame's image exists and has the
// size in camera.yaml; reads sensor.yaml when present; with read_ground_truth
// and a gt/ folder present, reads and checks it too (one latent, depth and
// pose per frame, HR sizes equal).
Sequence ReadSequence(const std::string& folder, bool read_ground_truth);
// Writes sensor.yaml when readout_time > 0 and removes a stale one otherwise.
void WriteSequence(const std::string& folder, const Sequence& sequence);

}  // namespace deblur_sr_mvs
