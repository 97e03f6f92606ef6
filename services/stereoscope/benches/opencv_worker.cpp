// OpenCV from C++ on the moment worker's frames: no interpreter in the timed loop
// (docs/performance.md, "Moment worker against OpenCV"). Built and run by compare-live.sh:
//
//   g++ -O2 -std=c++17 opencv_worker.cpp $(pkg-config --cflags --libs opencv4) -lpthread
//   opencv_worker FRAMES_DIR WORKER.json OUT.json [--quick]
//
// FRAMES_DIR and WORKER.json are what `cargo bench -p stereoscope --bench live -- --frames-dir`
// wrote: 120 frames (a second at 120 fps) and, per frame, the worker's threshold and blobs.
// The frames are played as the worker's bench plays them: forward and back in turn
// (ping-pong), 25 passes of 120 frames (5 with --quick), the median pass reported; one thread,
// cv::setNumThreads(1). Two algorithms, each under the worker bench's three conditions:
//
// - full: what a user without the worker writes: every frame threshold + findContours
//   (external, simple) + cv::moments per contour; every 30th frame a histogram of every
//   `threshold_rows_step`-th row (cv::calcHist) and the worker's `auto` rule on it.
// - windowed: the best windowed OpenCV we could write: every 10th frame (the worker's search
//   period) the full pass above; on the others, threshold + findContours + moments inside a
//   window round each blob of the frame before (its box grown by its own size, at least
//   15 px, each side; windows that overlap are merged), the histogram as above.
//
// Conditions: frames from memory (each read where it lies), frames just written (copied by
// this thread into one buffer just before it is timed) and frames handed over by another
// thread (two buffers, one in flight: what the worker bench's `delivered` does).
//
// Before timing, both algorithms are checked against the worker on every frame: the same
// blobs (contours of at least 4 pixels, edge blobs left out as the Python script does) with
// centroids within 0.5 px, the windowed one after a pass to warm its windows. Exit 1 naming
// the first frame that differs.

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <fstream>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

using json = nlohmann::json;
using Clock = std::chrono::steady_clock;

struct Blob {
  double x, y;
  int pixels;
  bool edge;
  cv::Rect box;
};

static const int MIN_AREA = 4;
static const double TOLERANCE_PX = 0.5;
static const int SEARCH_EVERY = 10;

// The worker's `auto` threshold (services/lib/vision/src/histogram.rs), as opencv_worker.py.
static int auto_threshold(const cv::Mat &hist) {
  std::vector<double> h(256);
  for (int i = 0; i < 256; i++) h[i] = hist.at<float>(i);
  int hi = -1;
  for (int i = 255; i >= 0; i--)
    if (h[i] != 0) { hi = i; break; }
  if (hi < 0) return 1;
  int peak = int(std::max_element(h.begin(), h.end()) - h.begin());
  int knee;
  if (peak >= hi) {
    knee = hi + 1;
  } else {
    double x0 = peak, y0 = h[peak], dx = double(hi + 1) - x0, dy = -y0;
    double norm = std::sqrt(dx * dx + dy * dy);
    int best = peak + 1;
    double bestd = -1e300;
    for (int l = peak + 1; l <= hi; l++) {
      double d = ((l - x0) * dy - (h[l] - y0) * dx) / norm;
      if (d > bestd) { bestd = d; best = l; }
    }
    knee = (bestd > -1.0 ? best : peak) + 1;
  }
  double n = 0, s = 0;
  for (int l = knee; l < 256; l++) { n += h[l]; s += l * h[l]; }
  int t = n == 0 ? knee : int(std::floor((knee + s / n) / 2.0 + 0.5));
  return std::min(std::max(t, 1), 255);
}

static int frame_threshold(const cv::Mat &img, int rows_step) {
  cv::Mat rows;
  for (int y = 0; y < img.rows; y += rows_step) rows.push_back(img.row(y));
  int channels[] = {0};
  int size[] = {256};
  float range[] = {0, 256};
  const float *ranges[] = {range};
  cv::Mat hist;
  cv::calcHist(&rows, 1, channels, cv::Mat(), hist, 1, size, ranges);
  return auto_threshold(hist);
}

// Threshold + contours + moments in `roi` of `img` (offset into frame coordinates).
struct Finder {
  cv::Mat binary;
  std::vector<std::vector<cv::Point>> contours;

  // With `inner`: contours touching the window's edge inside the frame are left out (a blob
  // the window cuts is not one it tracks; the next full pass finds it whole).
  void find(const cv::Mat &img, cv::Rect roi, int t, std::vector<Blob> &out, bool count,
            cv::Rect inner = cv::Rect()) {
    cv::Mat part = img(roi);
    cv::threshold(part, binary, t - 1, 255, cv::THRESH_BINARY);
    cv::findContours(binary, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
    for (auto &c : contours) {
      cv::Moments m = cv::moments(c);
      cv::Rect b = cv::boundingRect(c);
      int pixels = count ? cv::countNonZero(binary(b)) : int(m.m00) + 1;
      if (pixels < MIN_AREA || m.m00 <= 0) continue;
      cv::Rect box(b.x + roi.x, b.y + roi.y, b.width, b.height);
      if (inner.area() > 0 &&
          ((b.x == 0 && roi.x > 0) || (b.y == 0 && roi.y > 0) ||
           (b.x + b.width >= roi.width && roi.x + roi.width < inner.width) ||
           (b.y + b.height >= roi.height && roi.y + roi.height < inner.height)))
        continue;
      bool edge = box.x == 0 || box.y == 0 || box.x + box.width >= img.cols ||
                  box.y + box.height >= img.rows;
      out.push_back({m.m10 / m.m00 + roi.x, m.m01 / m.m00 + roi.y, pixels, edge, box});
    }
  }
};

struct Full {
  Finder f;
  std::vector<Blob> blobs;
  int every, rows_step;
  void reset() {}
  const std::vector<Blob> &step(const cv::Mat &img, int t, long i, bool count = false) {
    if (i % every == 0) frame_threshold(img, rows_step);
    blobs.clear();
    f.find(img, cv::Rect(0, 0, img.cols, img.rows), t, blobs, count);
    return blobs;
  }
};

struct Windowed {
  Finder f;
  std::vector<Blob> blobs, last;
  std::vector<cv::Rect> windows;
  int every, rows_step;
  void reset() { last.clear(); }
  const std::vector<Blob> &step(const cv::Mat &img, int t, long i, bool count = false) {
    if (i % every == 0) frame_threshold(img, rows_step);
    blobs.clear();
    cv::Rect frame(0, 0, img.cols, img.rows);
    if (i % SEARCH_EVERY == 0 || last.empty()) {
      f.find(img, frame, t, blobs, count);
    } else {
      windows.clear();
      for (auto &b : last) {
        int gx = std::max(15, b.box.width), gy = std::max(15, b.box.height);
        cv::Rect w(b.box.x - gx, b.box.y - gy, b.box.width + 2 * gx, b.box.height + 2 * gy);
        windows.push_back(w & frame);
      }
      // Overlapping windows merged until none overlap: every tracked blob lies whole in one.
      for (bool again = true; again;) {
        again = false;
        for (size_t a = 0; a < windows.size() && !again; a++)
          for (size_t b = a + 1; b < windows.size(); b++)
            if ((windows[a] & windows[b]).area() > 0) {
              windows[a] |= windows[b];
              windows.erase(windows.begin() + long(b));
              again = true;
              break;
            }
      }
      for (auto &w : windows) f.find(img, w, t, blobs, count, frame);
    }
    last = blobs;
    return blobs;
  }
};

static size_t ping_pong(long i, size_t n) {
  size_t k = size_t(i) % (2 * n);
  return k < n ? k : 2 * n - 1 - k;
}

static double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

struct Frame {
  cv::Mat img;
  int t;
  std::vector<std::array<double, 3>> theirs;  // x, y, area of the worker's non-edge blobs
  std::string name;
};

// The same blobs as the worker's on every frame; returns the worst centroid distance.
template <class A>
static double check(A &a, const std::vector<Frame> &frames, const char *what, long &matched) {
  a.reset();
  double worst = 0;
  long n = long(frames.size());
  // One ping-pong round to warm a windowed finder's windows, then the check.
  for (long i = 0; i < 2 * n; i++) a.step(frames[ping_pong(i, frames.size())].img, frames[ping_pong(i, frames.size())].t, i, true);
  for (long i = 2 * n; i < 3 * n; i++) {
    const Frame &fr = frames[ping_pong(i, frames.size())];
    std::vector<Blob> ours;
    for (auto &b : a.step(fr.img, fr.t, i, true))
      if (!b.edge) ours.push_back(b);
    if (ours.size() != fr.theirs.size()) {
      fprintf(stderr, "%s: frame %s: OpenCV finds %zu blobs at threshold %d, the worker %zu\n", what,
              fr.name.c_str(), ours.size(), fr.t, fr.theirs.size());
      exit(1);
    }
    for (auto &w : fr.theirs) {
      double d = 1e300;
      for (auto &b : ours) d = std::min(d, std::hypot(w[0] - b.x, w[1] - b.y));
      if (d > TOLERANCE_PX) {
        fprintf(stderr, "%s: frame %s: the worker's blob at (%.2f, %.2f) is %.2f px from every OpenCV blob\n",
                what, fr.name.c_str(), w[0], w[1], d);
        exit(1);
      }
      worst = std::max(worst, d);
      matched++;
    }
  }
  return worst;
}

// ms a frame, median pass, three conditions: {memory, written, handed}.
template <class A>
static std::array<double, 3> time_all(A &a, const std::vector<Frame> &frames, long total) {
  size_t n = frames.size();
  std::array<double, 3> out{};
  // From memory.
  {
    a.reset();
    std::vector<double> passes;
    auto t0 = Clock::now();
    for (long i = 0; i < total; i++) {
      const Frame &fr = frames[ping_pong(i, n)];
      a.step(fr.img, fr.t, i);
      if ((i + 1) % long(n) == 0) {
        passes.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count() / n);
        t0 = Clock::now();
      }
    }
    out[0] = median(passes);
  }
  // Just written by this thread.
  {
    a.reset();
    cv::Mat staging = frames[0].img.clone();
    std::vector<double> passes;
    double spent = 0;
    for (long i = 0; i < total; i++) {
      const Frame &fr = frames[ping_pong(i, n)];
      fr.img.copyTo(staging);
      auto t0 = Clock::now();
      a.step(staging, fr.t, i);
      spent += std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
      if ((i + 1) % long(n) == 0) { passes.push_back(spent / n); spent = 0; }
    }
    out[1] = median(passes);
  }
  // Handed over by another thread: two buffers, one in flight at a time.
  {
    a.reset();
    cv::Mat bufs[2] = {frames[0].img.clone(), frames[0].img.clone()};
    std::mutex m;
    std::condition_variable cv_;
    long ready = -1, taken = -1;  // the frame index in flight, the last one the timer took
    std::thread producer([&] {
      for (long i = 0; i < total; i++) {
        {
          std::unique_lock<std::mutex> l(m);
          // The buffer i % 2 is free once frame i - 2 was processed (and i - 1 taken).
          cv_.wait(l, [&] { return taken >= i - 1; });
        }
        frames[ping_pong(i, n)].img.copyTo(bufs[i % 2]);
        {
          std::lock_guard<std::mutex> l(m);
          ready = i;
        }
        cv_.notify_all();
      }
    });
    std::vector<double> passes;
    double spent = 0;
    for (long i = 0; i < total; i++) {
      {
        std::unique_lock<std::mutex> l(m);
        cv_.wait(l, [&] { return ready >= i; });
        taken = i;
      }
      cv_.notify_all();
      auto t0 = Clock::now();
      a.step(bufs[i % 2], frames[ping_pong(i, n)].t, i);
      spent += std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
      if ((i + 1) % long(n) == 0) { passes.push_back(spent / n); spent = 0; }
    }
    producer.join();
    out[2] = median(passes);
  }
  return out;
}

int main(int argc, char **argv) {
  if (argc < 4) {
    fprintf(stderr, "usage: opencv_worker FRAMES_DIR WORKER.json OUT.json [--quick]\n");
    return 2;
  }
  std::string dir = argv[1];
  bool quick = argc > 4 && std::string(argv[4]) == "--quick";
  cv::setNumThreads(1);
  std::ifstream in(argv[2]);
  json worker = json::parse(in, nullptr, false);
  if (worker.is_discarded()) {
    fprintf(stderr, "%s: not JSON\n", argv[2]);
    return 1;
  }
  if (worker.value("threshold_method", "") != "Auto") {
    fprintf(stderr, "the worker's threshold is not `auto`\n");
    return 1;
  }
  int every = worker["threshold_every_frames"], rows_step = worker["threshold_rows_step"];
  std::vector<Frame> frames;
  for (auto &f : worker["frames"]) {
    Frame fr;
    fr.name = f["frame"];
    fr.img = cv::imread(dir + "/" + fr.name + ".pgm", cv::IMREAD_UNCHANGED);
    if (fr.img.empty()) {
      fprintf(stderr, "%s/%s.pgm: OpenCV cannot read it\n", dir.c_str(), fr.name.c_str());
      return 1;
    }
    fr.t = f["threshold"];
    int own = frame_threshold(fr.img, rows_step);
    if (own != int(f["own_threshold"])) {
      fprintf(stderr, "frame %s: calcHist and the auto rule give %d, the worker's code %d\n",
              fr.name.c_str(), own, int(f["own_threshold"]));
      return 1;
    }
    for (auto &b : f["blobs"])
      if (!b[3].get<bool>()) fr.theirs.push_back({b[0].get<double>(), b[1].get<double>(), b[2].get<double>()});
    frames.push_back(std::move(fr));
  }
  Full full{};
  full.every = every;
  full.rows_step = rows_step;
  Windowed win{};
  win.every = every;
  win.rows_step = rows_step;
  long matched_full = 0, matched_win = 0;
  double worst_full = check(full, frames, "full", matched_full);
  double worst_win = check(win, frames, "windowed", matched_win);
  long total = long(frames.size()) * (quick ? 5 : 25);
  auto f = time_all(full, frames, total);
  auto w = time_all(win, frames, total);
  json out = {
      {"opencv_version", CV_VERSION},
      {"frames", frames.size()},
      {"frame", std::to_string(frames[0].img.cols) + "x" + std::to_string(frames[0].img.rows)},
      {"blobs_matched_full", matched_full},
      {"blobs_matched_windowed", matched_win},
      {"worst_centroid_px_full", worst_full},
      {"worst_centroid_px_windowed", worst_win},
      {"full_ms", f[0]},
      {"full_ms_written", f[1]},
      {"full_ms_handed", f[2]},
      {"windowed_ms", w[0]},
      {"windowed_ms_written", w[1]},
      {"windowed_ms_handed", w[2]},
  };
  std::ofstream(argv[3]) << out.dump() << "\n";
  return 0;
}
