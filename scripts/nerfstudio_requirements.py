"""Print nerfstudio's install requirements for this platform, one a line, minus the ones we leave out.

Run with the Python of the environment that holds nerfstudio (installed with --no-deps first)."""

from importlib.metadata import requires

from pip._vendor.packaging.requirements import Requirement

# opencv-python-headless: a second OpenCV into the cv2/ folder of opencv-contrib-python-headless;
# nuscenes-devkit pins an old OpenCV too; the rest are notebooks, experiment trackers, tunnels,
# downloaders and a mesh library that ns-train never needs on this path
LEFT_OUT = {"opencv-python-headless", "nuscenes-devkit", "jupyterlab", "wandb", "comet-ml", "pyngrok",
            "gdown", "pymeshlab"}
# imported by nerfstudio but not declared by it
ADDED = ["pyyaml", "rawpy"]


def main() -> None:
    lines = []
    for text in requires("nerfstudio") or []:
        requirement = Requirement(text)
        if requirement.marker is not None and not requirement.marker.evaluate({"extra": ""}):
            continue
        if requirement.name.lower() in LEFT_OUT:
            continue
        requirement.marker = None
        lines.append(str(requirement))
    print("\n".join(lines + ADDED))


if __name__ == "__main__":
    main()
