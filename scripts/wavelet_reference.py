#!/usr/bin/env python3
"""Writes tests/data/wavelet_reference.json: PyWavelets' periodized transforms of fixed random
inputs, which tests/wavelet.rs compares with envlight::wavelet to 1e-9.

    python3 -m venv /tmp/pywt && /tmp/pywt/bin/pip install pywavelets numpy
    /tmp/pywt/bin/python scripts/wavelet_reference.py > tests/data/wavelet_reference.json

2-D cases: pywt.coeffs_to_array(pywt.wavedec2(x, name, mode="periodization", level=L)) — the
Mallat layout envlight uses (coarsest approximation top-left; per level 'ad' top-right, 'da'
bottom-left, 'dd' bottom-right), row-major. 1-D cases: the concatenation of pywt.wavedec(...)
= [cA_L, cD_L, ..., cD_1]. Inputs are standard normal (numpy default_rng(2026)), stored as
shortest round-trip decimals so Rust reads the same f64 values; outputs are rounded to 13
significant digits to keep the file small.
"""
import json
import warnings
import sys

import numpy as np
import pywt

ALL = ["haar"] + [f"db{n}" for n in range(2, 11)] + [f"coif{n}" for n in range(1, 6)]
ISSUE = ["haar", "db2", "db3", "db4", "coif1", "coif2"]

# Deep levels are the point here (pywt warns that every coefficient sees the boundary).
warnings.simplefilter("ignore", UserWarning)

rng = np.random.default_rng(2026)


def floats(a):
    """Exact f64 values (inputs)."""
    return [float(v) for v in np.asarray(a).ravel()]


def rounded(a):
    """13 significant digits (outputs; the test's tolerance is 1e-9 of the largest magnitude)."""
    return [float(f"{v:.13g}") for v in np.asarray(a).ravel()]


cases_2d = []
x16 = rng.standard_normal((16, 16))
x32 = rng.standard_normal((32, 32))
for name in ALL:
    for level in (1, 4):
        arr, _ = pywt.coeffs_to_array(pywt.wavedec2(x16, name, mode="periodization", level=level))
        cases_2d.append({"basis": name, "side": 16, "levels": level, "input": "x16", "coefficients": rounded(arr)})
for name in ISSUE:
    for level in (2, 5):
        arr, _ = pywt.coeffs_to_array(pywt.wavedec2(x32, name, mode="periodization", level=level))
        cases_2d.append({"basis": name, "side": 32, "levels": level, "input": "x32", "coefficients": rounded(arr)})

cases_1d = []
s64 = rng.standard_normal(64)
for name in ALL:
    level = 6
    coeffs = pywt.wavedec(s64, name, mode="periodization", level=level)
    cases_1d.append({"basis": name, "len": 64, "levels": level, "coefficients": rounded(np.concatenate(coeffs))})

json.dump(
    {
        "generator": "scripts/wavelet_reference.py",
        "pywavelets": pywt.__version__,
        "numpy": np.__version__,
        "mode": "periodization",
        "inputs": {"x16": floats(x16), "x32": floats(x32), "s64": floats(s64)},
        "cases_2d": cases_2d,
        "cases_1d": cases_1d,
    },
    sys.stdout,
    separators=(",", ":"),
)
sys.stdout.write("\n")
