/* OpenEXR files through OpenEXR 3.1's C++ library.
 *
 * Why C++ in a C library: the bundled environment maps use DWAB compression, which OpenEXR 3.1
 * decodes only in its C++ library (OpenEXRCore's C decoder answers "not yet implemented"), and
 * the library's C interface (ImfCRgbaFile.h) passes pixels as half floats, which would round
 * every value read or written to 11 bits. Imf::InputFile reads any compression, scanline or
 * tiled, half/float/uint channels, into 32-bit float slices; Imf::OutputFile writes 32-bit float
 * channels with ZIP compression (lossless). No exception leaves this file. */
#include <cjson/cJSON.h>
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

extern "C" {
#include "io/io_internal.h"
}

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>

#include <cstring>
#include <exception>
#include <stdexcept>
#include <string>

namespace {

/* Slice base pointer such that pixel (x, y) of the data window lands at row-major offset
 * ((y - y0) * width + (x - x0)) * channels + c, computed in integers so that no out-of-range
 * pointer is formed before OpenEXR adds the offsets back. */
char *slice_base(float *data, int x0, int y0, int width, int channels, int c) {
    ptrdiff_t offset = (-(ptrdiff_t)y0 * width - x0) * channels + c;
    return reinterpret_cast<char *>(reinterpret_cast<uintptr_t>(data) +
                                    offset * (ptrdiff_t)sizeof(float));
}

/* A file held in memory as an OpenEXR input stream: reads past the end throw, as a truncated
 * file does. */
class MemoryStream : public Imf::IStream {
  public:
    MemoryStream(const char *name, const unsigned char *bytes, size_t size)
        : Imf::IStream(name), bytes_(bytes), size_(size), pos_(0) {}
    bool read(char c[], int n) override {
        if (n < 0 || pos_ > size_ || (uint64_t)n > size_ - pos_)
            throw std::runtime_error("unexpected end of file at byte offset " +
                                     std::to_string(pos_));
        memcpy(c, bytes_ + pos_, (size_t)n);
        pos_ += (uint64_t)n;
        return pos_ < size_;
    }
    uint64_t tellg() override { return pos_; }
    void seekg(uint64_t pos) override { pos_ = pos; }

  private:
    const unsigned char *bytes_;
    uint64_t size_, pos_;
};

/* R, G, B (or Y) of an opened file into out; `path` names it in messages. OpenEXR errors are
 * thrown (the callers catch them). */
pen_status read_rgb(pen_context *ctx, const char *path, Imf::InputFile &file,
               pen_image *out) {
    const Imf::Header &h = file.header();
    Imath::Box2i dw = h.dataWindow();
    long long w = (long long)dw.max.x - dw.min.x + 1, hh = (long long)dw.max.y - dw.min.y + 1;
    /* Each side and the pixel budget, like every decoder, before the pixels exist. */
    pen_status size_status = pen__image_check_size(ctx, path, w, hh);
    if (size_status) return size_status;
    const Imf::ChannelList &ch = h.channels();
    const char *names[3] = {"R", "G", "B"};
    bool rgb = ch.findChannel("R") && ch.findChannel("G") && ch.findChannel("B");
    if (!rgb && !ch.findChannel("Y"))
        return pen__error(ctx, PEN_ERROR_UNSUPPORTED, "%s: no R, G, B or Y channels", path);
    for (Imf::ChannelList::ConstIterator it = ch.begin(); it != ch.end(); ++it)
        if (it.channel().xSampling != 1 || it.channel().ySampling != 1)
            return pen__error(ctx, PEN_ERROR_UNSUPPORTED,
                              "%s: channel %s is subsampled (not supported)", path, it.name());
    pen_status s = pen_image_create(ctx, (int)w, (int)hh, 3, out);
    if (s) return s;
    /* A frame buffer holds one slice per channel name, so grey is read into the first
     * channel and copied to the others afterwards. */
    Imf::FrameBuffer fb;
    const size_t xs = 3 * sizeof(float), ys = xs * (size_t)w;
    for (int c = 0; c < (rgb ? 3 : 1); ++c)
        fb.insert(rgb ? names[c] : "Y",
                  Imf::Slice(Imf::FLOAT,
                             slice_base(out->data, dw.min.x, dw.min.y, (int)w, 3, c), xs, ys, 1,
                             1, 0.0));
    file.setFrameBuffer(fb);
    file.readPixels(dw.min.y, dw.max.y);
    if (!rgb)
        for (size_t i = 0; i < (size_t)w * (size_t)hh; ++i)
            out->data[3 * i + 1] = out->data[3 * i + 2] = out->data[3 * i];
    return PEN_OK;
}

/* Called inside a catch-all handler: rethrows the exception being handled to record it as one
 * error line, and frees the partial image. */
pen_status caught(pen_context *ctx, const char *path, pen_image *out) {
    pen_image_free(out);
    try {
        throw;
    } catch (const std::exception &e) {
        return pen__error(ctx, PEN_ERROR_PARSE, "%s: OpenEXR: %s", path, e.what());
    } catch (...) {
        return pen__error(ctx, PEN_ERROR_INTERNAL, "%s: OpenEXR failed", path);
    }
}

} // namespace

extern "C" pen_status pen__exr_load(pen_context *ctx, const char *path, pen_image *out) {
    *out = pen_image{};
    try {
        Imf::InputFile file(path);
        return read_rgb(ctx, path, file, out);
    } catch (...) {
        return caught(ctx, path, out);
    }
}

extern "C" pen_status pen__exr_decode(pen_context *ctx, const char *name,
                                      const unsigned char *bytes, size_t size, pen_image *out) {
    *out = pen_image{};
    try {
        MemoryStream stream(name, bytes, size);
        Imf::InputFile file(stream);
        return read_rgb(ctx, name, file, out);
    } catch (...) {
        return caught(ctx, name, out);
    }
}

extern "C" pen_status pen__exr_save(pen_context *ctx, const char *path, const char *file_name,
                                    const pen_image *image) {
    try {
        const int w = image->width, h = image->height, n = image->channels;
        static const char *const layouts[5][4] = {
            {nullptr}, {"Y"}, {"Y", "A"}, {"R", "G", "B"}, {"R", "G", "B", "A"}};
        Imf::Header header(w, h);
        header.compression() = Imf::ZIP_COMPRESSION;
        Imf::FrameBuffer fb;
        const size_t xs = (size_t)n * sizeof(float), ys = xs * (size_t)w;
        for (int c = 0; c < n; ++c) {
            header.channels().insert(layouts[n][c], Imf::Channel(Imf::FLOAT));
            fb.insert(layouts[n][c],
                      Imf::Slice(Imf::FLOAT, slice_base(image->data, 0, 0, w, n, c), xs, ys));
        }
        Imf::OutputFile file(file_name, header);
        file.setFrameBuffer(fb);
        file.writePixels(h);
        return PEN_OK;
    } catch (const std::exception &e) {
        return pen__error(ctx, PEN_ERROR_IO, "%s: OpenEXR: %s", path, e.what());
    } catch (...) {
        return pen__error(ctx, PEN_ERROR_INTERNAL, "%s: OpenEXR failed", path);
    }
}
