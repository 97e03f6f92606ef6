// OpenCV from C++ on the moment engine bench's frames: threshold, and threshold + findContours
// + cv::moments per contour, one thread, no interpreter in the timed loop (docs/performance.md,
// "Moment engine"). Built and run by compare-opencv.sh:
//
//   g++ -O2 -std=c++17 opencv_engine.cpp $(pkg-config --cflags --libs opencv4)
//   opencv_engine FRAMES_DIR THRESHOLD OUT.json [--quick]
//
// Each frame's time is the median of 11 batches (3 with --quick) of at least 25 ms (10 ms),
// the frame re-read from cache: the rule of opencv_bench.py and of the Rust bench.

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

using Clock = std::chrono::steady_clock;

static double time_ms(const std::function<void()> &fn, int batches, double min_batch_s) {
  auto start = Clock::now();
  long n = 0;
  while (std::chrono::duration<double>(Clock::now() - start).count() < min_batch_s / 4 || n < 3) {
    fn();
    n++;
  }
  double per_call = std::chrono::duration<double>(Clock::now() - start).count() / n;
  long iters = std::max(3L, long(min_batch_s / per_call) + 1);
  std::vector<double> samples;
  for (int b = 0; b < batches; b++) {
    auto t = Clock::now();
    for (long i = 0; i < iters; i++) fn();
    samples.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t).count() / iters);
  }
  std::sort(samples.begin(), samples.end());
  return samples[samples.size() / 2];
}

int main(int argc, char **argv) {
  if (argc < 4) {
    fprintf(stderr, "usage: opencv_engine FRAMES_DIR THRESHOLD OUT.json [--quick]\n");
    return 2;
  }
  bool quick = argc > 4 && std::string(argv[4]) == "--quick";
  int batches = quick ? 3 : 11;
  double min_batch = quick ? 0.010 : 0.025;
  int t = std::stoi(argv[2]);
  cv::setNumThreads(1);
  std::vector<std::filesystem::path> paths;
  for (auto &e : std::filesystem::directory_iterator(argv[1]))
    if (e.path().extension() == ".pgm") paths.push_back(e.path());
  std::sort(paths.begin(), paths.end());
  std::ofstream out(argv[3]);
  out << "[\n";
  for (size_t k = 0; k < paths.size(); k++) {
    cv::Mat img = cv::imread(paths[k].string(), cv::IMREAD_UNCHANGED), binary;
    if (img.empty()) {
      fprintf(stderr, "%s: OpenCV cannot read it\n", paths[k].c_str());
      return 1;
    }
    std::vector<std::vector<cv::Point>> contours;
    std::vector<cv::Moments> moments;
    auto threshold = [&] { cv::threshold(img, binary, t - 1, 255, cv::THRESH_BINARY); };
    auto full = [&] {
      cv::threshold(img, binary, t - 1, 255, cv::THRESH_BINARY);
      cv::findContours(binary, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
      moments.clear();
      for (auto &c : contours) moments.push_back(cv::moments(c));
    };
    full();
    size_t found = contours.size();
    double th = time_ms(threshold, batches, min_batch), fu = time_ms(full, batches, min_batch);
    out << "{\"frame\":\"" << paths[k].stem().string() << "\",\"opencv_version\":\"" CV_VERSION
        << "\",\"contour_blobs\":" << found << ",\"threshold_ms\":" << th << ",\"contours_ms\":" << fu
        << "}" << (k + 1 < paths.size() ? ",\n" : "\n");
  }
  out << "]\n";
  return 0;
}
