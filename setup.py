"""hybrid-calib: target-free radar-camera extrinsic calibration (learned + factor graph)."""

from setuptools import find_packages, setup

setup(
    name="hybrid-calib",
    version="0.1.0",
    description="Target-free radar-camera extrinsic calibration: RC-AutoCalib + robust factor graphs",
    python_requires=">=3.10",
    packages=find_packages(include=["hybrid_calib*", "factors*", "learned*"]),
    package_data={"learned": ["checkpoints/*.safetensors", "checkpoints/*.json"]},
    install_requires=[
        # torch must be installed first as exactly torch==2.13.0 (local CPU build); see Makefile.
        "torch==2.13.0",
        "gtsam==4.3.0",  # pulls pytest>=9
        "pyceres==2.6",
        "numpy>=2,<2.5",
        "scipy>=1.13,<2",
        "opencv-python-headless>=4.10,<5",
        "tqdm>=4.66,<5",
        "safetensors>=0.4,<1",
        "matplotlib>=3.8,<4",
    ],
    extras_require={
        "dev": ["pytest>=9", "ruff==0.17.6", "hypothesis>=6.100"],
        # learned.depth.DepthAnythingEstimator (metric Depth Anything from a local directory)
        "depth": ["transformers==5.23.0"],
        # hybrid-calib fleet --engine ray (hybrid_calib.fleet.engines); make test installs it
        "fleet": ["ray>=2.40,<3"],
        # benchmarks/bench_simulate.py compares our ray caster against trimesh + Embree
        "bench": ["trimesh>=4,<6", "embreex==4.4.0.post1"],
    },
    entry_points={"console_scripts": ["hybrid-calib=hybrid_calib.cli:main"]},
)
