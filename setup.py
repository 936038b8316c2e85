"""ament_python package definition; also a plain pip-installable setuptools package.

colcon installs the console scripts to lib/roi_node (setup.cfg), the ament index
marker to share/ament_index/resource_index/packages, and package.xml, config/ and
launch/ to share/roi_node, where `ros2 run`, `ros2 launch` and the runtime config
lookup find them.
"""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "roi_node"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "bench", "examples"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", sorted(glob("config/*.*"))),
        (f"share/{PACKAGE}/launch", sorted(glob("launch/*.launch.py"))),
    ],
    python_requires=">=3.11",
    # OpenCV 4.x, not 5.x: a system ROS 2 Jazzy install (Ubuntu 24.04) ships
    # python3-opencv 4.6, and 5.0 reorganised calib3d/fisheye; pinning the venv
    # to the 4.x major keeps what the tests exercise equal to what a colcon
    # install on a real rig runs.
    install_requires=[
        "numpy>=1.26",
        # the exact area resampling kernel (roi_node/engine/area_kernels.py); wheels, no compiler needed
        "numba>=0.59",
        "opencv-python-headless>=4.8,<5",
        "placo>=0.9",
        "pyyaml>=6.0",
        "jsonschema>=4.17",
    ],
    extras_require={
        "ros": ["ros-jazzy-rclpy[fastrtps]>=7.1", "ros-jazzy-common-interfaces>=5.3"],
        # lz4 and zstandard: the chunk compressions roi_node's MCAP writer offers; zlib-ng: fast chunk CRCs (bagio/crc.py);
        # backports.zstd: multi-frame zstd chunks, as rosbags reads them (bagio/indexed_mcap.py)
        "bag": ["rosbags>=0.10,<0.12", "mcap>=1.2", "mcap-ros2-support>=0.5", "lz4>=4", "zstandard>=0.22", "zlib-ng>=0.5",
                "backports.zstd>=1.0; python_version<'3.14'"],
        # trimesh reads the URDF meshes the visibility render draws (pycollada: its .dae reader)
        "robots": ["example-robot-data>=4.1", "trimesh>=4", "pycollada>=0.8"],
        # `roi-node export lerobot`: parquet + video without torch (PyAV's wheels bundle SVT-AV1 and x264)
        "export": ["av>=14", "pyarrow>=15"],
        # `roi-node sign` / `verify`: OpenSSF model-signing; its certificate verifier imports pyOpenSSL, which 1.1 does not declare
        "sign": ["model-signing>=1.1,<2", "pyOpenSSL>=24"],
        # `--ray`: one task per bag on a Ray cluster; 2.52 is the first with token authentication (RAY_AUTH_TOKEN)
        "cluster": ["ray>=2.52,<3"],
        # `--policy grpc://`: LeRobot's async-inference PolicyServer (messages framed by hand: no protobuf, no lerobot);
        # torch reads the tensors its action chunks are pickled as
        "grpc": ["grpcio>=1.66", "torch>=2.2"],
        # `policy run --policy ws://`: openpi's websocket policy servers through openpi-client. openpi-client 0.1.2 pins
        # numpy<2, which the robots extra's pinocchio wheels (numpy 2.3) exclude, so the Makefile installs it with
        # --no-deps (its code runs on numpy 2) after these, its own requirements
        "openpi": ["msgpack>=1.0.5", "websockets>=11", "pillow>=9", "typing-extensions>=4"],
        "dev": [
            "pytest>=8,<9",  # pytest 9 renamed the node id pytest-xdist's loadgroup rewrites (its groups are ignored)
            "pytest-timeout>=2.3",
            "pytest-xdist>=3.5",  # make test: the DDS tests on one worker, the rest beside them
            "ruff>=0.6",
            "mypy>=1.10",
            "types-PyYAML",
            "psutil>=5.9",
            "colcon-common-extensions>=0.3",
        ],
    },
    zip_safe=True,
    maintainer="roi_node developers",
    description="Hand-centric ROI crops from one fixed external camera via FK projection.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "roi-node = roi_node.cli:main",
            "roi_node = roi_node.cli:ros2_run_main",
            "roi_node_lifecycle = roi_node.cli:ros2_run_lifecycle_main",
        ],
    },
)
