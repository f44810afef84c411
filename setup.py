"""spgeo: dense monocular reconstruction with SuperPrimitives.

``factors/`` and ``evaluation/`` live at the top of the repository but are
installed as the sub-packages ``spgeo.factors`` and ``spgeo.evaluation``
(the top-level names are taken on PyPI and are never installed as such).
"""
from setuptools import find_packages, setup

# Ranges, not pins: spgeo installs beside whatever numpy/scipy/... an environment already
# holds, as long as it is within these ranges.  The exact versions CI runs are in
# constraints.txt (``pip install -c constraints.txt -e .``); the lower bounds below are
# constraints-lowest.txt, and the fast test tier has passed with them too; where an older
# release was tried and failed, the comment says how.  Upper bounds: none, as no break
# with a newer release is known; add one only with the reason beside it (scipy and numba
# cap numpy themselves).
INSTALL_REQUIRES = [
    "numpy>=2.0.2",          # opencv-contrib 5 and pandas (via evo) need numpy 2
    "scipy>=1.14.1",
    "gtsam>=4.3.0",
    "open3d>=0.19.0",
    "onnxruntime>=1.22.1",   # 1.20.1 cannot load the test models ("two nodes with same
                             # node name (/GatherSliceToSplitFusion/)")
    "opencv-contrib-python-headless>=5.0.0.93",  # with 4.12 the ORB+PnP baseline never starts
    "pycolmap>=4.2.1",       # 4.0.0 and 4.1.1 fail the ICL COLMAP-baseline test
    "evo>=1.38.1",
    "tqdm>=4.66.1",
    "platformdirs>=4.2.0",
    "threadpoolctl>=3.1.0",
    "numba>=0.61.2",
]

_NOTEBOOKS = ["matplotlib>=3.11.2", "ipykernel>=7.4.0"]
EXTRAS = {
    # what tests/ imports beyond install_requires (onnx builds the contract models)
    "test": ["pytest>=9.0.3", "onnx>=1.23.2", "nbclient>=0.11.0", "nbformat>=5.11.1",
             "PyYAML>=6.0.3"] + _NOTEBOOKS,
    "notebooks": _NOTEBOOKS,
    "viz": ["rerun-sdk>=0.41.0"],            # spgeo.viz / --rerun
    "distributed": ["ray>=2.60.0"],          # spgeo eval --workers / --address
}
EXTRAS["all"] = sorted({r for reqs in EXTRAS.values() for r in reqs})

setup(
    name="spgeo",
    version="0.1.0",
    description="Dense monocular 3D reconstruction with SuperPrimitives (GTSAM back-end)",
    long_description=open("README.md", encoding="utf-8").read(),
    long_description_content_type="text/markdown",
    license="MIT",
    # the versions the test suite has run on; 3.14 is left out only because no 3.14
    # interpreter has run it yet (the binary dependencies do publish 3.14 wheels)
    python_requires=">=3.11,<3.14",
    classifiers=[
        "Programming Language :: Python :: 3",
        "Programming Language :: Python :: 3.11",
        "Programming Language :: Python :: 3.12",
        "Programming Language :: Python :: 3.13",
        "License :: OSI Approved :: MIT License",
        "Operating System :: POSIX :: Linux",
        "Intended Audience :: Science/Research",
        "Topic :: Scientific/Engineering :: Image Recognition",
    ],
    # every sub-package of spgeo/, plus factors/ and evaluation/ under the spgeo name
    packages=(["spgeo"] + [f"spgeo.{p}" for p in find_packages("spgeo")]
              + ["spgeo.factors", "spgeo.evaluation"]
              + [f"spgeo.evaluation.{p}" for p in find_packages("evaluation")]),
    package_dir={
        "spgeo": "spgeo",
        "spgeo.factors": "factors",
        "spgeo.evaluation": "evaluation",
    },
    package_data={"spgeo": ["data/*.md", "data/*.txt", "data/tum_fr1_desk_9/*.txt",
                            "data/tum_fr1_desk_9/*.md",
                            "data/tum_fr1_desk_9/rgb/*.png", "data/tum_fr1_desk_9/depth/*.png"]},
    include_package_data=True,
    install_requires=INSTALL_REQUIRES,
    extras_require=EXTRAS,
    entry_points={"console_scripts": ["spgeo=spgeo.cli:main"]},
)
