// imu_tk's multi-position calibration on two "time x y z" files, as imu_tk's own example app
// (apps/test_imu_calib.cpp) runs it on its Xsens recording: initial accelerometer bias 32768
// counts, gyro scale 1/6258 rad/s per count, a 50 s initial rest, g = 9.81744 m/s^2, every
// sample of the static intervals (not their means). Without the plots and the solver's progress
// output, so that what benchmarks/recording.py times is the calibration.
//
//   imu_tk_calib ACC_FILE GYRO_FILE OUT_PREFIX
// writes OUT_PREFIX_acc.calib and OUT_PREFIX_gyro.calib (imu_tk's own layout, which its
// CalibratedTriad::load reads: misalignment matrix, scale matrix, bias vector; but with 17
// significant digits, where its save() keeps 6) and prints both triads' parameters.
#include <fstream>
#include <iomanip>
#include <iostream>
#include <string>
#include <vector>

#include "imu_tk/calibration.h"
#include "imu_tk/io_utils.h"

using imu_tk::CalibratedTriad;
using imu_tk::MultiPosCalibration;
using imu_tk::TriadData;

static bool save_precise(const CalibratedTriad& triad, const std::string& path) {
  std::ofstream file(path.c_str());
  file << std::setprecision(17) << triad.getMisalignmentMatrix() << "\n\n"
       << triad.getScaleMatrix() << "\n\n" << triad.getBiasVector() << "\n";
  return bool(file);
}

int main(int argc, char** argv) {
  if (argc < 4) {
    std::cerr << "usage: imu_tk_calib ACC_FILE GYRO_FILE OUT_PREFIX" << std::endl;
    return 2;
  }
  std::vector<TriadData> acc_data, gyro_data;
  imu_tk::importAsciiData(argv[1], acc_data, imu_tk::TIMESTAMP_UNIT_SEC);
  imu_tk::importAsciiData(argv[2], gyro_data, imu_tk::TIMESTAMP_UNIT_SEC);
  if (acc_data.empty() || gyro_data.empty()) {
    std::cerr << "imu_tk_calib: no samples read from " << argv[1] << " or " << argv[2] << std::endl;
    return 2;
  }
  CalibratedTriad init_acc, init_gyro;
  init_acc.setBias(Eigen::Vector3d(32768, 32768, 32768));
  init_gyro.setScale(Eigen::Vector3d(1.0 / 6258.0, 1.0 / 6258.0, 1.0 / 6258.0));

  MultiPosCalibration calib;
  calib.setInitStaticIntervalDuration(50.0);
  calib.setInitAccCalibration(init_acc);
  calib.setInitGyroCalibration(init_gyro);
  calib.setGravityMagnitude(9.81744);
  calib.enableVerboseOutput(false);
  calib.enableAccUseMeans(false);
  if (!calib.calibrateAccGyro(acc_data, gyro_data)) {
    std::cerr << "imu_tk_calib: calibration failed" << std::endl;
    return 1;
  }
  const std::string prefix = argv[3];
  if (!save_precise(calib.getAccCalib(), prefix + "_acc.calib") ||
      !save_precise(calib.getGyroCalib(), prefix + "_gyro.calib")) {
    std::cerr << "imu_tk_calib: cannot write " << prefix << "_*.calib" << std::endl;
    return 2;
  }
  std::cout.precision(10);
  std::cout << "accelerometer" << std::endl << calib.getAccCalib() << "gyroscope" << std::endl
            << calib.getGyroCalib();
  return 0;
}
