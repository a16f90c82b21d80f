"""Image files the validation reads and writes: Radiance RGBE (.hdr, POV-Ray's +FH output),
PFM (freeform's irradiance and heightmaps) and PNG (through matplotlib)."""
import numpy as np


def read_hdr(path):
    """A Radiance RGBE picture as a float array (rows, cols, 3), row 0 the top of the picture.
    Handles flat pixels and the run-length encoded scanlines that POV-Ray writes."""
    data = open(path, "rb").read()
    # Header lines up to an empty line, then the resolution line "-Y h +X w".
    end = data.index(b"\n\n")
    header = data[:end].decode("ascii", "replace")
    if "32-bit_rle_rgbe" not in header and "FORMAT" in header:
        raise ValueError(f"{path}: not an RGBE picture")
    pos = end + 2
    nl = data.index(b"\n", pos)
    tokens = data[pos:nl].split()
    pos = nl + 1
    if len(tokens) != 4 or tokens[0] != b"-Y" or tokens[2] != b"+X":
        raise ValueError(f"{path}: unsupported orientation {tokens!r}")
    height, width = int(tokens[1]), int(tokens[3])
    buf = np.frombuffer(data, dtype=np.uint8, offset=pos)
    rgbe = np.empty((height, width, 4), dtype=np.uint8)
    p = 0
    for y in range(height):
        if width >= 8 and width < 32768 and buf[p] == 2 and buf[p + 1] == 2 and (buf[p + 2] << 8 | buf[p + 3]) == width:
            p += 4
            for c in range(4):
                x = 0
                row = rgbe[y, :, c]
                while x < width:
                    n = int(buf[p])
                    p += 1
                    if n > 128:  # a run of one value
                        n -= 128
                        row[x:x + n] = buf[p]
                        p += 1
                    else:  # n literal values
                        row[x:x + n] = buf[p:p + n]
                        p += n
                    x += n
        else:  # flat pixels
            rgbe[y] = buf[p:p + 4 * width].reshape(width, 4)
            p += 4 * width
    e = rgbe[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0)
    return rgbe[..., :3].astype(np.float64) * scale[..., None]


def read_pfm(path):
    """A PFM image as float64 (rows, cols) for grey, (rows, cols, 3) for colour; row 0 the top."""
    with open(path, "rb") as f:
        kind = f.readline().strip()
        dims = f.readline().split()
        while len(dims) < 2:
            dims += f.readline().split()
        width, height = int(dims[0]), int(dims[1])
        scale = float(f.readline())
        channels = 3 if kind == b"PF" else 1
        raw = np.fromfile(f, dtype="<f4" if scale < 0 else ">f4", count=width * height * channels)
    img = raw.reshape(height, width, channels) if channels == 3 else raw.reshape(height, width)
    return np.flipud(img).astype(np.float64)  # PFM stores the bottom row first


def write_pfm(path, img):
    img = np.asarray(img, dtype="<f4")
    with open(path, "wb") as f:
        f.write(b"Pf\n%d %d\n-1\n" % (img.shape[1], img.shape[0]))
        f.write(np.flipud(img).tobytes())
