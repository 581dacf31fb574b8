// OpenEXR output (exr.hpp) through OpenEXR's scan-line OutputFile, encoded
// into memory and then written atomically like every other image.
#include "voxcast/exr.hpp"

#include <Imath/half.h>
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfIO.h>
#include <OpenEXR/ImfOutputFile.h>
#include <fmt/format.h>

#include <algorithm>
#include <cstring>
#include <exception>

#include "voxcast/error.hpp"
#include "voxcast/progress.hpp"

namespace voxcast {

namespace {

// Rows per writePixels call (a multiple of the ZIP compressor's 16 lines).
constexpr int kExrStripRows = 256;
// Share of the write's time converting the channel planes (the rest:
// compressing the rows).
constexpr double kExrPlanesWeight = 0.35;

/// An Imf::OStream into a byte string.
class MemoryStream : public Imf::OStream {
 public:
  MemoryStream() : Imf::OStream("memory") {}
  void write(const char c[], int n) override {
    if (pos_ + size_t(n) > data_.size()) data_.resize(pos_ + size_t(n));
    std::memcpy(data_.data() + pos_, c, size_t(n));
    pos_ += size_t(n);
  }
  uint64_t tellp() override { return pos_; }
  void seekp(uint64_t pos) override { pos_ = size_t(pos); }
  const std::string& data() const { return data_; }

 private:
  std::string data_;
  size_t pos_ = 0;
};

}  // namespace

void write_exr(const std::filesystem::path& path, const std::vector<ExrChannel>& channels) {
  if (channels.empty()) throw Error(fmt::format("cannot write {}: no channel", path.string()));
  const Image& first = *channels[0].image;
  const int w = first.width, h = first.height;
  if (w <= 0 || h <= 0) throw Error(fmt::format("cannot write {}: empty image", path.string()));
  for (const ExrChannel& c : channels)
    if (!c.image || c.image->width != w || c.image->height != h || c.component < 0 ||
        c.component >= c.image->channels ||
        c.image->pixels.size() != size_t(w) * size_t(h) * size_t(c.image->channels))
      throw Error(fmt::format("cannot write {}: channel {} does not match the image", path.string(),
                              c.name));
  // One contiguous plane per channel (OpenEXR reads slices with strides; a
  // half plane needs converting anyway).
  std::vector<std::vector<half>> halves(channels.size());
  std::vector<std::vector<float>> floats(channels.size());
  // A bar on a terminal (a large multi-layer image takes seconds): the
  // channel planes converted, then the rows compressed, in strips of
  // kExrStripRows (a multiple of ZIP's 16-line blocks: the same file as one
  // writePixels call). Weights measured once at 8192^2 with RGBA, Z and N
  // (planes 4.9 s, encode and write 9.5 s).
  // (Named by the stage: the CLI writes to a temporary name, then renames.)
  Progress progress("write image",
                    {{"planes", kExrPlanesWeight}, {"encode", 1 - kExrPlanesWeight}});
  progress.start_phase(0, channels.size());
  try {
    Imf::Header header(w, h);
    header.compression() = Imf::ZIP_COMPRESSION;
    Imf::FrameBuffer fb;
    for (size_t i = 0; i < channels.size(); ++i) {
      const ExrChannel& c = channels[i];
      const size_t n = size_t(w) * size_t(h);
      const int stride = c.image->channels;
      if (c.half) {
        halves[i].resize(n);
        for (size_t p = 0; p < n; ++p)
          halves[i][p] = half(c.image->pixels[p * size_t(stride) + size_t(c.component)]);
        header.channels().insert(c.name, Imf::Channel(Imf::HALF));
        fb.insert(c.name, Imf::Slice(Imf::HALF, reinterpret_cast<char*>(halves[i].data()),
                                     sizeof(half), sizeof(half) * size_t(w)));
      } else {
        floats[i].resize(n);
        for (size_t p = 0; p < n; ++p)
          floats[i][p] = c.image->pixels[p * size_t(stride) + size_t(c.component)];
        header.channels().insert(c.name, Imf::Channel(Imf::FLOAT));
        fb.insert(c.name, Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(floats[i].data()),
                                     sizeof(float), sizeof(float) * size_t(w)));
      }
      progress.advance();
    }
    progress.start_phase(1, uint64_t(h));
    MemoryStream stream;
    {
      Imf::OutputFile file(stream, header);
      file.setFrameBuffer(fb);
      for (int y = 0; y < h; y += kExrStripRows) {
        const int rows = std::min(kExrStripRows, h - y);
        file.writePixels(rows);
        progress.advance(uint64_t(rows));
      }
    }
    write_file_atomic(path, stream.data().data(), stream.data().size());
    progress.finish();
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Error(fmt::format("cannot write {}: {}", path.string(), e.what()));
  }
}

void write_exr_image(const std::filesystem::path& path, const Image& image) {
  static const char* const kNames[4][4] = {
      {"Y"}, {"Y", "A"}, {"R", "G", "B"}, {"R", "G", "B", "A"}};
  if (image.channels < 1 || image.channels > 4)
    throw Error(fmt::format("cannot write {}: EXR images here have 1 to 4 channels, not {}",
                            path.string(), image.channels));
  std::vector<ExrChannel> channels;
  for (int c = 0; c < image.channels; ++c)
    channels.push_back({kNames[image.channels - 1][c], &image, c, true});
  write_exr(path, channels);
}

}  // namespace voxcast
