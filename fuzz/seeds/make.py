#!/usr/bin/env python3
"""Writes the seed corpora of the fuzz targets into fuzz/corpus/<target>/ from the
fixtures (kept small: one frame of the recorded dump, the camera files, the shipped
config, the fixture's scene) and from a few hand-made minimal inputs. Run by fuzz/run
before fuzzing; the corpus directories are not committed (libFuzzer grows them)."""
import os, struct, sys, zlib

root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
fix = os.path.join(root, "fixtures", "sim-bricks")
out = os.path.join(root, "fuzz", "corpus")


def put(target, name, data):
    d = os.path.join(out, target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def read(*p):
    with open(os.path.join(*p), "rb") as f:
        return f.read()


def dump_header(fourcc, w, h, bpl, dev=b"/dev/video0", card=b"fuzz"):
    b = b"CRSLDUMP" + struct.pack("<II", 1, 42 + 2 + len(dev) + len(card) + 4 + 2 - 2)
    b = bytearray(b)
    body = fourcc + struct.pack("<IIIII", w, h, bpl, 1, 30)
    body += struct.pack("<H", len(dev)) + dev + struct.pack("<H", len(card)) + card
    length = 16 + len(body) + 4
    b[12:16] = struct.pack("<I", length)
    b += body
    return bytes(b) + struct.pack("<I", zlib.crc32(bytes(b)))


def record(seq, ts, payload):
    r = b"FRAM" + struct.pack("<IQII", seq, ts, 0, len(payload)) + payload
    return r + struct.pack("<I", zlib.crc32(r))


# Dump: the fixture's header and first frame, and a tiny RGB3 and YUYV dump.
d = read(fix, "frames.dump")
hl = struct.unpack_from("<I", d, 12)[0]
used = struct.unpack_from("<I", d, hl + 20)[0]
first = d[: hl + 24 + used + 4]
put("dump", "fixture-first-frame.dump", first)
put("dump", "rgb3.dump", dump_header(b"RGB3", 4, 2, 12) + record(1, 0, bytes(range(24))) + record(2, 33_000_000, bytes(24)))
put("dump", "yuyv.dump", dump_header(b"YUYV", 4, 2, 0) + record(1, 0, bytes([16, 128] * 8)))

# decode_rgb: selector, width u16, height u16, bytes per line u16, payload.
jpeg = d[hl + 24 : hl + 24 + used]
put("decode_rgb", "mjpg", bytes([0]) + struct.pack("<HHH", 480, 270, 0) + jpeg)
put("decode_rgb", "yuyv", bytes([1]) + struct.pack("<HHH", 4, 2, 8) + bytes([81, 90, 81, 240] * 4))
put("decode_rgb", "rgb3", bytes([2]) + struct.pack("<HHH", 4, 2, 12) + bytes(range(24)))

# Camera files.
put("camera_yaml", "opencv.yml", read(fix, "camera.yml"))
put("camera_yaml", "ros.yaml", read(fix, "camera_info.yaml"))
put("camera_toml", "camera.toml", b"[camera]\nwidth = 1920\nheight = 1080\nfx = 1400.0\nfy = 1400.0\ncx = 959.5\ncy = 539.5\nskew = 0.0\ndistortion = [-0.1, 0.02, 0.0, 0.0, 0.0]\n")

# Config and scene.
put("config", "crossline.toml", read(root, "config", "crossline.toml"))
put("config", "serve.toml", b"[serve]\nworkers = 2\ncheckpoint_interval_s = 0.5\n[solve]\nrefine_rounds = 3\n")
put("scene", "bricks.toml", read(fix, "scene.toml"))

# PLY, ASCII and binary.
put("ply", "ascii.ply", b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n0 0 1 255 0 0\n1 2 3 0 255 0\n")
body = struct.pack("<fffBBB", 0, 0, 1, 1, 2, 3) + struct.pack("<fffBBB", 1, 2, 3, 4, 5, 6)
put("ply", "binary.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n" + body)

# Checkpoint log: header (640x480) and one frame with one curve.
rec = b"FRCV" + struct.pack("<QQIQI", 0, 3, 100, 33_000_000, 1)
rec += bytes([0]) + struct.pack("<I", 2)
for i in range(2):
    rec += struct.pack("<ffddf", 1.5 + i, 2.0, 0.1 * i, -0.2, 40.0)
rec += struct.pack("<I", 2) + struct.pack("<dddd", 0.1, -0.2, 0.3, 0.4)
rec += struct.pack("<I", zlib.crc32(rec))
put("checkpoint", "one-frame.log", b"CRSLCURV" + struct.pack("<III", 1, 640, 480) + rec)


# Cloud stream: HELLO, EPOCH, POINTS (2), END.
def msg(kind, body):
    return struct.pack("<I", 1 + len(body)) + bytes([kind]) + body


pts = b"".join(struct.pack("<fffBBBBI", i, 0, 1, 255, 0, 0, 0, i) for i in range(2))
stream = msg(1, b"CRSLSTRM" + struct.pack("<I", 1) + b'{"width":640,"height":480}')
stream += msg(2, struct.pack("<IB", 1, 0)) + msg(3, struct.pack("<IQI", 1, 5, 2) + pts)
stream += msg(4, struct.pack("<IQ", 1, 2))
put("stream", "epoch.bin", stream)

# Status lines.
put("status", "lines.jsonl", b'{"type":"event","event":"final_solve","detail":"capture stopped"}\n{"type":"status","device":"streaming"}\n')
print("seeds written to", out, file=sys.stderr)
