"""spgeo: dense monocular reconstruction with SuperPrimitives.

``factors/`` and ``evaluation/`` live at the top of the repository but are
installed as the sub-packages ``spgeo.factors`` and ``spgeo.evaluation``
(the top-level names are taken on PyPI and are never installed as such).
"""
from setuptools import find_packages, setup

# Versions tested together on Python 3.11 (x86-64, CPU).  gtsam wheels have
# crashed with some numpy 2 builds upstream; this pair is exercised by the tests.
INSTALL_REQUIRES = [
    "numpy==2.4.6",
    "scipy==1.17.1",
    "gtsam==4.3.0",
    "open3d==0.20.0",
    "onnxruntime==1.31.1",
    "opencv-contrib-python-headless==5.0.0.93",
    "pycolmap==4.2.1",
    "evo==1.38.1",
    "tqdm==4.70.1",
    "platformdirs==4.14.7",
    "threadpoolctl==3.8.0",
    "numba==0.68.1",
]

EXTRAS = {
    "test": [
        "pytest==9.0.3",
        "onnx==1.23.2",
        "nbclient==0.11.0",
        "nbformat==5.11.1",
        "ipykernel==7.4.0",
        "matplotlib==3.11.2",
    ],
    "notebooks": ["matplotlib==3.11.2", "ipykernel==7.4.0"],
}

setup(
    name="spgeo",
    version="0.1.0",
    description="Dense monocular 3D reconstruction with SuperPrimitives (GTSAM back-end)",
    long_description=open("README.md", encoding="utf-8").read(),
    long_description_content_type="text/markdown",
    license="MIT",
    python_requires=">=3.11,<3.12",
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
