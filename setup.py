"""Build the compiled kernels (diagnose/csrc) as the extension ``diagnose._kernels`` at install time.

Portable flags only: no -march=native (the library carries baseline, AVX2 and AVX-512 variants and
picks one when it loads), no fused multiply-add and no fast-math (results equal on every CPU).
Everything else is in pyproject.toml.
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "diagnose._kernels",
            sources=["diagnose/csrc/kernels.c"],
            depends=["diagnose/csrc/valve_step.h", "diagnose/csrc/kernels_lanes.h"],
            extra_compile_args=["-O3", "-std=gnu99", "-ffp-contract=off", "-fno-fast-math"],
        )
    ],
)
