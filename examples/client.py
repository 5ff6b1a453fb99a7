#!/usr/bin/env python3
"""Minimal envlight client using only the Python standard library.

Connects to a running daemon over a Unix socket or TCP, subscribes (binary frames, or JSON
lines with --json), and prints one line per light list (or per ASG set with --representation
asg, per wavelet coefficient set with --representation wavelet, per spherical-harmonic set with
--representation sh). The wire format is docs/protocol.md; both forms are checked as it asks of
a decoder (lengths, finite numbers, known representations, ASG lobes, wavelet sets, error texts).

    python3 examples/client.py unix:/run/envlight/envlight.sock
    python3 examples/client.py 127.0.0.1:7878 --max-lights 16 --frames 10
    python3 examples/client.py 127.0.0.1:7878 --json   # JSON lines (json module) instead
    python3 examples/client.py 127.0.0.1:7878 --representation asg   # needs [asg] enabled
    python3 examples/client.py 127.0.0.1:7878 --representation wavelet   # needs [wavelet] enabled
    python3 examples/client.py 127.0.0.1:7878 --representation sh   # needs [sh] enabled
"""

import argparse
import json
import math
import os
import socket
import struct
import sys

MAGIC = b"ENVL"
VERSION = 1
TYPE_FRAME, TYPE_ERROR, TYPE_GOODBYE, TYPE_SUBSCRIBE = 1, 2, 3, 16
MAX_MESSAGE_LEN = 1 << 20
# A server's JSON message may be up to 8 MiB (docs/protocol.md, "JSON form").
MAX_JSON_MESSAGE_LEN = 8 << 20
REPRESENTATIONS = {"lights": 0, "asg": 1, "wavelet": 2, "sh": 3}
MAX_SH_DEGREE = 15
BASES = {1: "haar", **{n: f"db{n}" for n in range(2, 11)}, **{16 + n: f"coif{n}" for n in range(1, 6)}}


def parse_address(address):
    """("unix", path) or ("tcp", (host, port)); ValueError with the reason for anything else."""
    if "://" in address:
        raise ValueError("this client speaks the binary protocol over unix: or TCP; "
                         "for ws:// use `envlight subscribe`")
    if address.startswith("unix:") or "/" in address:
        path = address[5:] if address.startswith("unix:") else address
        if not path:
            raise ValueError("unix: needs a socket path")
        return "unix", path
    host, _, port = address.removeprefix("tcp:").rpartition(":")
    if not host or not port.isdigit() or int(port) > 65535:
        raise ValueError("expected unix:PATH, a socket path, HOST:PORT or tcp:HOST:PORT")
    return "tcp", (host.strip("[]"), int(port))


def connect(kind, target):
    if kind == "unix":
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.connect(target)
    else:
        sock = socket.create_connection(target)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def count(limit):
    """An argparse type: an integer in 0..=limit."""
    def parse(text):
        value = int(text)
        if not 0 <= value <= limit:
            raise argparse.ArgumentTypeError(f"{value} is not in 0..={limit}")
        return value
    return parse


def subscribe_message(max_lights, representation=0):
    # length, magic, version, type | max_lights, representation (0 = lights, 1 = asg, 2 = wavelet,
    # 3 = sh), format 0 = binary, reserved
    body = struct.pack("<IBBH", max_lights, representation, 0, 0)
    return struct.pack("<I4sHH", 8 + len(body), MAGIC, VERSION, TYPE_SUBSCRIBE) + body


def json_subscribe_message(max_lights, representation="lights"):
    """The subscribe as one JSON line: everything the server sends is then JSON lines."""
    request = {"max_lights": max_lights, "representation": representation, "format": "json"}
    return (json.dumps({"subscribe": request}) + "\n").encode()


def read_exact(sock, n):
    data = bytearray()
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise EOFError("the daemon closed the connection")
        data += chunk
    return bytes(data)


def read_message(sock):
    (length,) = struct.unpack("<I", read_exact(sock, 4))
    if length < 8 or length > MAX_MESSAGE_LEN:
        raise ValueError(f"bad length prefix {length}")
    payload = read_exact(sock, length)
    magic, version, kind = struct.unpack_from("<4sHH", payload)
    if magic != MAGIC:
        raise ValueError(f"bad magic {magic!r}")
    if version != VERSION:
        raise ValueError(f"unsupported version {version}")
    return kind, payload[8:]


class LineReader:
    """JSON lines from a socket, each at most MAX_JSON_MESSAGE_LEN bytes."""

    def __init__(self, sock):
        self.sock, self.buffer = sock, bytearray()

    def binary_first(self):
        """A socket-like reader of the stream from its start if its first bytes are a binary
        message (the magic at bytes 4..8; a JSON line starts with '{'), else None."""
        while len(self.buffer) < 8:
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                break
            self.buffer += chunk
        if self.buffer[4:8] != MAGIC:
            return None
        return BufferedSocket(bytes(self.buffer), self.sock)

    def message(self):
        """The next line, parsed: a dict; ValueError for a line that is too long or not an
        object; EOFError at the end of the stream."""
        while True:
            end = self.buffer.find(b"\n")
            if end >= 0:
                line = bytes(self.buffer[:end])
                del self.buffer[:end + 1]
                break
            if len(self.buffer) > MAX_JSON_MESSAGE_LEN:
                raise ValueError(f"a JSON line longer than {MAX_JSON_MESSAGE_LEN} bytes")
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                raise EOFError("the daemon closed the connection")
            self.buffer += chunk
        if len(line) > MAX_JSON_MESSAGE_LEN:
            raise ValueError(f"a JSON line of {len(line)} bytes (at most {MAX_JSON_MESSAGE_LEN})")
        # JSON has no NaN or infinity: Python's own extensions are refused.
        value = json.loads(line, parse_constant=lambda name: _refuse(f"{name} is not JSON"))
        if not isinstance(value, dict):
            raise ValueError(f"a JSON message is an object, not {type(value).__name__}")
        return value


class BufferedSocket:
    """`recv` of bytes already read, then of the socket."""

    def __init__(self, data, sock):
        self.data, self.sock = data, sock

    def recv(self, n):
        if self.data:
            chunk, self.data = self.data[:n], self.data[n:]
            return chunk
        return self.sock.recv(n)


def _refuse(reason):
    raise ValueError(reason)


def numbers(value, n, what):
    """`value` as a tuple of n floats; ValueError naming `what` otherwise."""
    if not isinstance(value, list) or len(value) != n or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
        raise ValueError(f"{what} is not a list of {n} numbers: {value!r}")
    floats = tuple(float(x) for x in value)
    # json reads 1e400 as an infinity.
    if not all(math.isfinite(x) for x in floats):
        raise ValueError(f"{what} holds a number beyond range (error 1)")
    return floats


def number(value, what):
    return numbers([value], 1, what)[0]


# Within this of 1, |axis| and |tangent| of an ASG lobe, and at most this |axis . tangent|
# (docs/protocol.md: the fit's values rounded to f32).
ASG_TOLERANCE = 1e-3
MAX_WAVELET_SIDE = 32768


def check_lobes(lobes, where):
    """docs/protocol.md's checks of ASG lobes: lambda, mu and integral > 0, an orthonormal
    frame (within ASG_TOLERANCE); ValueError naming the lobe otherwise."""
    for i, g in enumerate(lobes):
        axis, tangent = g["axis"], g["tangent"]
        norms = [math.sqrt(sum(c * c for c in v)) for v in (axis, tangent)]
        dot = sum(a * t for a, t in zip(axis, tangent))
        if not (g["lambda"] > 0 and g["mu"] > 0 and g["integral"] > 0):
            raise ValueError(f"{where} lobe {i}: lambda, mu and integral must be > 0 (error 1)")
        if any(abs(n - 1) > ASG_TOLERANCE for n in norms) or abs(dot) > ASG_TOLERANCE:
            raise ValueError(f"{where} lobe {i}: axis and tangent are no orthonormal pair "
                             f"(|axis| {norms[0]:.4g}, |tangent| {norms[1]:.4g}, "
                             f"axis.tangent {dot:.3g}; error 1)")


def check_wavelet_set(side, levels, indices, where):
    """docs/protocol.md's checks of a wavelet set: a side that is a power of two in
    2..=32768, at most log2(side) levels, indices < side^2 and strictly increasing."""
    if not (isinstance(side, int) and 2 <= side <= MAX_WAVELET_SIDE and side & (side - 1) == 0):
        raise ValueError(f"{where}: side {side!r} is not a power of two in 2..={MAX_WAVELET_SIDE} "
                         "(error 1)")
    if not (isinstance(levels, int) and 0 <= levels <= side.bit_length() - 1):
        raise ValueError(f"{where}: levels {levels!r} is not in 0..=log2(side {side}) (error 1)")
    previous = -1
    for index in indices:
        if not previous < index < side * side:
            raise ValueError(f"{where}: index {index} is not above {previous} and below "
                             f"side^2 = {side * side} (error 1)")
        previous = index


def parse_json_frame(message):
    """The frame of a JSON message, in the form `parse_frame` gives for binary ones, with the
    same checks (docs/protocol.md, "JSON form": unknown fields are ignored)."""
    seq, time = message.get("seq"), number(message.get("time"), "time")
    if not isinstance(seq, int) or isinstance(seq, bool) or seq < 0:
        raise ValueError(f"seq {seq!r} is not a frame number")
    name = message.get("representation", "lights")
    if name not in REPRESENTATIONS:
        raise ValueError(f"frame of unknown representation {name!r} (error 5)")
    stale = message.get("stale", False)
    if not isinstance(stale, bool):
        raise ValueError(f"frame {seq}: stale {stale!r} is not true or false")
    representation = REPRESENTATIONS[name]
    frame = {"seq": seq, "time": time, "stale": stale, "representation": representation}
    where = f"frame {seq}"

    def records(key):
        items = message.get(key)
        if not isinstance(items, list):
            raise ValueError(f"{where}: {key} is not a list")
        return items

    if representation == 3:
        degree = message.get("degree")
        if not isinstance(degree, int) or not 0 <= degree <= MAX_SH_DEGREE:
            raise ValueError(f"{where}: SH degree {degree!r} is not in 0..={MAX_SH_DEGREE} (error 1)")
        sh = [numbers(c, 3, f"{where} SH coefficient {i}") for i, c in enumerate(records("sh"))]
        if len(sh) != (degree + 1) ** 2:
            raise ValueError(f"{where} has {len(sh)} SH coefficients for degree {degree} (error 1)")
        frame.update(degree=degree, sh=sh)
    elif representation == 2:
        side, levels, basis = message.get("side"), message.get("levels"), message.get("basis")
        if basis not in BASES.values():
            raise ValueError(f"{where}: unknown wavelet basis {basis!r} (error 1)")
        coefficients = []
        for i, c in enumerate(records("coefficients")):
            if not (isinstance(c, list) and len(c) == 2 and isinstance(c[0], int)
                    and not isinstance(c[0], bool)):
                raise ValueError(f"{where}: coefficient {i} is not [index, [r, g, b]]")
            coefficients.append((c[0], numbers(c[1], 3, f"{where} coefficient {i}")))
        check_wavelet_set(side, levels, [index for index, _ in coefficients], where)
        frame.update(basis=basis, levels=levels, side=side, coefficients=coefficients)
    elif representation == 1:
        frame["lobes"] = objects(records("lobes"), f"{where} lobe", LOBE_FIELDS)
        check_lobes(frame["lobes"], where)
    else:
        frame["lights"] = objects(records("lights"), f"{where} light", LIGHT_FIELDS)
    return frame


# The numbers of a JSON light and lobe (docs/protocol.md), each with its count: 1 is a number,
# 3 a list of three.
LIGHT_FIELDS = (("dir", 3), ("rgb", 3), ("solid_angle", 1))
LOBE_FIELDS = (("axis", 3), ("tangent", 3), ("lambda", 1), ("mu", 1), ("rgb", 3), ("integral", 1))


def objects(items, what, fields):
    """The records of a JSON frame's list `items` ("frame 7 light" is `what`): each an object
    with an id and the numbers of `fields`; ValueError naming the record and field otherwise."""
    out = []
    for i, item in enumerate(items):
        if not isinstance(item, dict):
            raise ValueError(f"{what} {i} is not an object")
        record = {"id": item.get("id")}
        for key, n in fields:
            value = item.get(key) if n > 1 else [item.get(key)]
            found = numbers(value, n, f"{what} {i} {key}")
            record[key] = found if n > 1 else found[0]
        out.append(record)
    return out


# Per representation code: the bytes of its fields after `count`, and of each record.
LAYOUTS = {0: (0, 32), 1: (0, 52), 2: (8, 16), 3: (4, 12)}


def parse_frame(body):
    """The frame in `body` (the message after its type) with every check docs/protocol.md asks
    of a decoder; ValueError naming the problem."""
    seq, time, representation, flags, _reserved, count = struct.unpack_from("<QdBBHI", body)
    if representation not in LAYOUTS:
        raise ValueError(f"frame of unknown representation {representation} (error 5)")
    prefix, record = LAYOUTS[representation]
    if len(body) != 24 + prefix + record * count:
        raise ValueError(f"frame of {count} records is {len(body) + 12} bytes, "
                         f"not {36 + prefix + record * count} (error 1)")
    frame = {"seq": seq, "time": time, "stale": bool(flags & 1), "representation": representation}
    if representation == 3:
        # Prefix: degree L, basis (0 = real orthonormal, the only one), reserved u16; then
        # (L + 1)^2 records of rgb, coefficient l^2 + l + m for Y_l^m.
        degree, basis, _reserved = struct.unpack_from("<BBH", body, 24)
        if basis != 0:
            raise ValueError(f"SH frame {seq} has unknown basis code {basis} (error 1)")
        if degree > MAX_SH_DEGREE:
            raise ValueError(f"SH frame {seq} has degree {degree} > {MAX_SH_DEGREE} (error 1)")
        if count != (degree + 1) ** 2:
            raise ValueError(f"SH frame {seq} has {count} coefficients for degree {degree} (error 1)")
        sh = [struct.unpack_from("<3f", body, 28 + 12 * i) for i in range(count)]
        frame.update(degree=degree, sh=sh)
        floats = [x for rgb in sh for x in rgb]
    elif representation == 2:
        # Prefix: basis code, levels, map (0 = equal-area octahedral), reserved, side; then
        # records of index (row * side + column in the coefficient layout) and rgb.
        basis, levels, map_code, _reserved, side = struct.unpack_from("<BBBBI", body, 24)
        if basis not in BASES or map_code != 0:
            raise ValueError(f"wavelet frame {seq}: unknown basis code {basis} or map code "
                             f"{map_code} (error 1)")
        coefficients = [struct.unpack_from("<I3f", body, 32 + 16 * i) for i in range(count)]
        check_wavelet_set(side, levels, [c[0] for c in coefficients], f"wavelet frame {seq}")
        frame.update(basis=BASES[basis], levels=levels, side=side,
                     coefficients=[(c[0], c[1:4]) for c in coefficients])
        floats = [x for c in coefficients for x in c[1:4]]
    elif representation == 1:
        # ASG lobe: id, axis, tangent (bitangent = axis x tangent), lambda, mu, rgb, integral.
        lobes = []
        for i in range(count):
            f = struct.unpack_from("<I3f3fff3ff", body, 24 + 52 * i)
            lobes.append({"id": f[0], "axis": f[1:4], "tangent": f[4:7], "lambda": f[7], "mu": f[8],
                          "rgb": f[9:12], "integral": f[12]})
        frame["lobes"] = lobes
        floats = [x for g in lobes for k in ("axis", "tangent", "rgb") for x in g[k]]
        floats += [x for g in lobes for x in (g["lambda"], g["mu"], g["integral"])]
    else:
        lights = []
        for i in range(count):
            fields = struct.unpack_from("<I3f3ff", body, 24 + 32 * i)
            lights.append({"id": fields[0], "dir": fields[1:4], "rgb": fields[4:7],
                           "solid_angle": fields[7]})
        frame["lights"] = lights
        floats = [x for field in lights for x in (*field["dir"], *field["rgb"], field["solid_angle"])]
    if not all(math.isfinite(x) for x in [time, *floats]):
        raise ValueError(f"frame {seq} holds a NaN or an infinity (error 1)")
    if representation == 1:
        check_lobes(frame["lobes"], f"ASG frame {seq}")
    return frame


def sh_irradiance(sh, degree, normal):
    """Irradiance (W/m^2 per channel) of a surface of unit `normal` under an SH set:
    E(n) = sum_l A_l sum_m L_lm Y_lm(n) (Ramamoorthi & Hanrahan 2001), A_l = pi, 2 pi / 3, pi / 4,
    0, -pi / 24, ... (0 for odd l > 1), Y_lm the basis of docs/protocol.md: Re, Im of (x + iy)^m
    times K_l^m P_l^m(z) / sin^m, the last by the three-term recurrence in l."""
    x, y, z = normal

    def band_factor(l):
        if l < 2:
            return (math.pi, 2 * math.pi / 3)[l]
        if l % 2:
            return 0.0
        half = l // 2
        central = math.comb(l, half) / 4 ** half
        return 2 * math.pi * (1 if half % 2 else -1) * central / ((l + 2) * (l - 1))

    out = [0.0, 0.0, 0.0]
    re, im, q_diagonal = 1.0, 0.0, 1.0
    for m in range(degree + 1):
        if m > 0:
            re, im = re * x - im * y, re * y + im * x
            q_diagonal *= 2 * m - 1
        q_before, q = 0.0, q_diagonal
        for l in range(m, degree + 1):
            if l > m:
                q_before, q = q, ((2 * l - 1) * z * q - (l + m - 1) * q_before) / (l - m)
            norm = math.sqrt((2 * l + 1) / (4 * math.pi) * math.factorial(l - m) / math.factorial(l + m))
            weight = band_factor(l) * norm * q * (math.sqrt(2) if m else 1.0)
            for c in range(3):
                if m == 0:
                    out[c] += weight * sh[l * l + l][c]
                else:
                    out[c] += weight * (sh[l * l + l + m][c] * re + sh[l * l + l - m][c] * im)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("address", help="unix:PATH, a socket path, HOST:PORT or tcp:HOST:PORT")
    parser.add_argument("--max-lights", type=count(2**32 - 1), default=0,
                        help="at most N lights per frame (0 = all)")
    parser.add_argument("--frames", type=count(2**63), default=0,
                        help="stop after N frames (0 = until goodbye)")
    parser.add_argument("--representation", choices=sorted(REPRESENTATIONS), default="lights",
                        help="directional lights, ASG lobes, wavelet coefficients or spherical "
                             "harmonics (--max-lights then caps the lobes or coefficients; SH: "
                             "the bands that fit, 4 = degrees 0 and 1)")
    parser.add_argument("--json", action="store_true",
                        help="subscribe with a JSON line and read JSON lines (docs/protocol.md, "
                             "\"JSON form\") instead of binary frames")
    args = parser.parse_args()
    try:
        kind, target = parse_address(args.address)
    except ValueError as e:
        parser.error(f"{args.address}: {e}")
    try:
        return stream(connect(kind, target), args)
    except BrokenPipeError:
        # The reader of our output went away (| head): not an error. Point stdout at
        # /dev/null so the interpreter's final flush does not fail again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (OSError, EOFError, ValueError, struct.error) as e:
        print(f"error: {args.address}: {e}", file=sys.stderr)
        return 1


def binary_messages(sock):
    """(kind, frame or (code, text)) of each binary message."""
    while True:
        kind, body = read_message(sock)
        if kind == TYPE_FRAME:
            yield kind, parse_frame(body)
        elif kind in (TYPE_ERROR, TYPE_GOODBYE):
            yield kind, closing_message(body)
        else:
            yield kind, None


def closing_message(body):
    """(code, text) of an error or goodbye body (after the header), checked as
    docs/protocol.md asks: text_len equal to the bytes left, the text valid UTF-8."""
    code, text_len = struct.unpack_from("<HI", body)
    if text_len != len(body) - 6:
        raise ValueError(f"an error or goodbye of {len(body) - 6} text bytes says {text_len} "
                         "(error 1)")
    try:
        return code, body[6:].decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"an error or goodbye text is not UTF-8: {e} (error 1)") from None


def json_messages(sock):
    """The same from JSON lines. The first reply may be binary all the same: a daemon at its
    client limit refuses a connection before reading its subscribe (error 100, docs/protocol.md),
    so it cannot know the form asked."""
    lines = LineReader(sock)
    binary = lines.binary_first()
    if binary is not None:
        yield from binary_messages(binary)
    while True:
        message = lines.message()
        for key, kind in (("error", TYPE_ERROR), ("goodbye", TYPE_GOODBYE)):
            if isinstance(message.get(key), dict):
                body = message[key]
                yield kind, (body.get("code"), str(body.get("message")))
                break
        else:
            yield TYPE_FRAME, parse_json_frame(message)


def stream(sock, args):
    if args.json:
        sock.sendall(json_subscribe_message(args.max_lights, args.representation))
        messages = json_messages(sock)
    else:
        sock.sendall(subscribe_message(args.max_lights, REPRESENTATIONS[args.representation]))
        messages = binary_messages(sock)
    frames = 0
    while args.frames == 0 or frames < args.frames:
        kind, content = next(messages)
        if kind == TYPE_FRAME:
            frame = content
            stale = " (stale)" if frame["stale"] else ""
            items = frame[("lights", "lobes", "coefficients", "sh")[frame["representation"]]]
            what, extra = f"{len(items)} lights", ""
            if "sh" in frame:
                # As `envlight subscribe`: the integral of L, sqrt(4 pi) L_00, and the irradiance
                # of a surface facing up (+Y).
                what = f"SH degree {frame['degree']} ({len(items)} coefficients)"
                total = [math.sqrt(4 * math.pi) * items[0][c] for c in range(3)]
                up = sh_irradiance(items, frame["degree"], (0.0, 1.0, 0.0))
                extra = f", irradiance up [{up[0]:.4f}, {up[1]:.4f}, {up[2]:.4f}]"
            elif "coefficients" in frame:
                # The scaling coefficients (top-left block of side / 2^levels) give the integral:
                # sum of texels = 2^levels * sum of scaling coefficients, texel = 4 pi / side^2 sr.
                side, levels = frame["side"], frame["levels"]
                block = side >> levels
                scaling = [rgb for index, rgb in items if index // side < block and index % side < block]
                scale = 2 ** levels * 4 * math.pi / side ** 2
                total = [scale * sum(rgb[c] for rgb in scaling) for c in range(3)]
                what = f"{len(items)} wavelet coefficients ({frame['basis']} on {side}^2, {levels} levels)"
            elif "lobes" in frame:
                what = f"{len(items)} ASG lobes"
                total = [sum(g["rgb"][c] * g["integral"] for g in items) for c in range(3)]
            else:
                total = [sum(l["rgb"][c] for l in items) for c in range(3)]
            print(f"seq {frame['seq']} time {frame['time']:.3f} s: {what}, "
                  f"total rgb [{total[0]:.4f}, {total[1]:.4f}, {total[2]:.4f}]{extra}{stale}", flush=True)
            frames += 1
        elif kind in (TYPE_ERROR, TYPE_GOODBYE):
            code, text = content
            what = "goodbye" if kind == TYPE_GOODBYE else f"error {code}"
            print(f"{what}: {text}", file=sys.stderr)
            return 0 if kind == TYPE_GOODBYE else 1
        else:
            print(f"unknown message type {kind}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
