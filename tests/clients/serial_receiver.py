"""A client the project did not write: reads a Stereoscope serial link with pyserial (PyPI)
and decodes it following docs/protocol.md only (no Stereoscope code).

usage: serial_receiver.py PORT BAUD legacy|framed COUNT SECONDS
Prints one JSON line per packet decoded, until COUNT packets or SECONDS passed, then
{"done": ..., "bad": N} (frames dropped for a wrong length, CRC or version).
"""
import json
import struct
import sys
import time

import serial


def crc16_ccitt_false(data):
    crc = 0xFFFF
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def cobs_decode(data):
    out = bytearray()
    i = 0
    while i < len(data):
        code = data[i]
        if code == 0 or i + code > len(data):
            return None
        out += data[i + 1:i + code]
        i += code
        if code < 0xFF and i < len(data):
            out.append(0)
    return bytes(out)


def framed(stream):
    """Yields decoded packets, or None for a bad frame."""
    buf = bytearray()
    while True:
        chunk = yield
        buf += chunk
        while b"\x00" in buf:
            at = buf.index(b"\x00")
            frame, buf = bytes(buf[:at]), buf[at + 1:]
            payload = cobs_decode(frame)
            if payload is None or len(payload) != 22 or payload[0] != 1:
                stream.append(None)
                continue
            if crc16_ccitt_false(payload[:20]) != struct.unpack(">H", payload[20:22])[0]:
                stream.append(None)
                continue
            _, oid, seq, x, y, z, theta, flags = struct.unpack(">BHHiiiHB", payload[:20])
            stream.append({"object_id": oid, "sequence": seq, "x_mm": x, "y_mm": y, "z_mm": z,
                           "theta_cdeg": theta, "flags": flags})


def legacy(stream):
    buf = bytearray()
    while True:
        chunk = yield
        buf += chunk
        while len(buf) >= 10:
            window = bytes(buf[:10])
            x, y, z, theta = struct.unpack(">hhhH", window[1:9])
            if window[0] == 0x1B and window[9] == 0 and theta < 36000:
                stream.append({"x_cm": x, "y_cm": y, "z_cm": z, "theta_cdeg": theta})
                del buf[:10]
            else:
                del buf[:1]


def main():
    port, baud, mode, count, seconds = (sys.argv[1], int(sys.argv[2]), sys.argv[3],
                                        int(sys.argv[4]), float(sys.argv[5]))
    line = serial.Serial(port, baudrate=baud, bytesize=8, parity="N", stopbits=1, timeout=0.1)
    packets = []
    decoder = framed(packets) if mode == "framed" else legacy(packets)
    next(decoder)
    printed = 0
    bad = 0
    end = time.monotonic() + seconds
    while printed < count and time.monotonic() < end:
        data = line.read(256)
        if data:
            decoder.send(data)
        for p in packets:
            if p is None:
                bad += 1
            elif printed < count:
                print(json.dumps(p), flush=True)
                printed += 1
        packets.clear()
    print(json.dumps({"done": True, "packets": printed, "bad": bad}), flush=True)


if __name__ == "__main__":
    main()
