"""Runs an exported imu-fsda TorchScript model in Python, independently of tch.

Usage: check_torchscript.py MODEL.pt INPUT.bin B T OUTPUT.bin

INPUT.bin holds B*T*6 little-endian float32 (raw IMU, [B, T, 6]); OUTPUT.bin receives
B*T*3 little-endian float32 (the model's [B, T, 3] output). Called by tests/model_export.rs.
"""
import array
import sys

import torch


def main() -> int:
    model_path, input_path, b, t, output_path = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
    with open(input_path, "rb") as f:
        raw = array.array("f")
        raw.frombytes(f.read())
    if sys.byteorder != "little":
        raw.byteswap()
    if len(raw) != b * t * 6:
        print(f"input has {len(raw)} floats, expected {b * t * 6}", file=sys.stderr)
        return 2
    u = torch.tensor(raw, dtype=torch.float32).reshape(b, t, 6)
    module = torch.jit.load(model_path, map_location="cpu")
    module.eval()
    with torch.no_grad():
        y = module(u)
    if tuple(y.shape) != (b, t, 3) or y.dtype != torch.float32:
        print(f"output shape {tuple(y.shape)} {y.dtype}, expected ({b}, {t}, 3) float32", file=sys.stderr)
        return 3
    out = array.array("f", y.contiguous().reshape(-1).tolist())
    if sys.byteorder != "little":
        out.byteswap()
    with open(output_path, "wb") as f:
        f.write(out.tobytes())
    print(f"torch {torch.__version__}: ran {model_path} on [{b}, {t}, 6]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
