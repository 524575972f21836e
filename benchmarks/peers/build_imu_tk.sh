#!/bin/sh
# Build imu_tk (github.com/Kyle-ak/imu_tk, a public fork of Alberto Pretto's IMU-TK, BSD) into
# benchmarks/out/imu_tk with the small driver beside this script, and run it once on imu_tk's
# Xsens recording from tests/data/real (decompressed there into imu_tk's text format).
#
#   benchmarks/peers/build_imu_tk.sh
#
# Needs g++, libceres-dev and libeigen3-dev (Debian: apt-get install libceres-dev libeigen3-dev).
# The source: IMU_TK_SRC (a checkout, or a git directory such as a bare mirror), else a clone of
# IMU_TK_URL. Pinned at IMU_TK_COMMIT, the commit whose Xsens files are in tests/data/real.
# imu_tk's Qt/OpenGL plots are left out: calibration.cpp's one plot (verbose mode only) is
# patched out, visualization.cpp is not built.
set -eu
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
OUT="$ROOT/benchmarks/out/imu_tk"
IMU_TK_URL=${IMU_TK_URL:-https://github.com/Kyle-ak/imu_tk}
IMU_TK_COMMIT=${IMU_TK_COMMIT:-7780270fb9a227c79323199303f23989e689a89d}

rm -rf "$OUT/src" && mkdir -p "$OUT/src"
if [ -n "${IMU_TK_SRC:-}" ] && [ -d "$IMU_TK_SRC/.git" ]; then
    git -C "$IMU_TK_SRC" archive "$IMU_TK_COMMIT" | tar -x -C "$OUT/src"
elif [ -n "${IMU_TK_SRC:-}" ] && git --git-dir="$IMU_TK_SRC" rev-parse --git-dir >/dev/null 2>&1; then
    git --git-dir="$IMU_TK_SRC" archive "$IMU_TK_COMMIT" | tar -x -C "$OUT/src"
elif [ -n "${IMU_TK_SRC:-}" ]; then
    cp -r "$IMU_TK_SRC"/. "$OUT/src"
else
    git clone -q "$IMU_TK_URL" "$OUT/clone" && git -C "$OUT/clone" archive "$IMU_TK_COMMIT" | tar -x -C "$OUT/src"
fi

# No plots: the include of the Qt/OpenGL visualisation and the plot of the verbose mode go.
sed -i -e '/#include "imu_tk\/visualization.h"/d' -e '/Plot plot;/d' -e '/plot\.plotIntervals/d' \
    -e '/waitForKey();/d' "$OUT/src/src/calibration.cpp"
# Three setters are declared to return a value and return none: undefined behaviour that g++ -O2
# may compile into a crash. They return nothing: made void.
sed -i -e 's/_T setInitStaticIntervalDuration(/void setInitStaticIntervalDuration(/' \
    -e 's/int setIntarvalsNumSamples(/void setIntarvalsNumSamples(/' \
    -e 's/bool enableGyroBiasOptimization(/void enableGyroBiasOptimization(/' \
    "$OUT/src/include/imu_tk/calibration.h"

g++ -O2 -DNDEBUG -std=c++17 -I"$OUT/src/include" -I/usr/include/eigen3 \
    "$OUT/src/src/calibration.cpp" "$OUT/src/src/filters.cpp" "$OUT/src/src/io_utils.cpp" \
    "$HERE/imu_tk_calib.cpp" -lceres -lglog -o "$OUT/imu_tk_calib"

for triad in acc gyro; do
    gzip -dc "$ROOT/tests/data/real/imu_tk_xsens_$triad.mat.gz" > "$OUT/xsens_$triad.mat"
done
"$OUT/imu_tk_calib" "$OUT/xsens_acc.mat" "$OUT/xsens_gyro.mat" "$OUT/xsens"
echo "built $OUT/imu_tk_calib; its parameters on the Xsens recording: $OUT/xsens_acc.calib, $OUT/xsens_gyro.calib"
