"""From stereo images to a shared map: render a small team's stereo images, run the image
front-end on them, run the distributed filter, and compare the map with the true markers.

    python examples/images_to_map.py --robots 2 --steps 40 --out results/example-images

Needs the ``images`` extra (OpenCV): ``pip install 'teamslam[images]'``.

The renderer draws a textured room with fiducial markers (the objects) and writes, per robot,
``left/`` and ``right/`` PNG folders, ``camera.yaml``, ``timestamps.txt``, wheel odometry and
ground truth as TUM files, and the marker map. The front-end (``teamslam.frontend``) tracks
corners across frames and detects the markers in both images; its output is a team dataset
like any other, so the filter runs on it unchanged. With your own images, call
``dataset_from_images`` with your folders, camera file and odometry instead.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import teamslam as ts
from teamslam import api
from teamslam.datasets.images import dataset_from_images, rendered_team_inputs
from teamslam.sim.render import render_size


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=2, help="team size (default 2)")
    parser.add_argument("--steps", type=int, default=40, help="frames per robot − 1")
    parser.add_argument("--width", type=int, default=320, help="image width in pixels")
    parser.add_argument("--out", type=Path, default=Path("results/example-images"))
    args = parser.parse_args(argv)

    # 1. render: image folders and the truth (bag=False: no ROS 2 bag of the images)
    images = args.out / "images"
    size = render_size(args.width)  # image size, focal length and marker size to match
    team = api.simulate_images(
        images, robots=args.robots, steps=args.steps, bag=False, progress=False, **size
    )
    print(f"rendered {team.config.robots} robots × {team.config.steps + 1} stereo pairs")

    # 2. front-end: features and markers measured in the images, then saved as a dataset
    dataset = dataset_from_images(**rendered_team_inputs(images), progress=False)
    ts.datasets.save_dataset(dataset, args.out / "dataset")
    for record in dataset.metadata["images"]["robots"]:
        print(
            f"  {record['name']}: {record['stereo_observations_per_frame']:.0f} stereo "
            f"observations per frame; odometry: {record['odometry']}"
        )

    # 3. the filter: every robot with consensus with the others (the calibration of the noise
    #    levels from the data is automatic: a dataset from images carries no sensor model)
    run = ts.run(dataset, mode="consensus", out=args.out / "run", progress=False)
    metrics = run.metrics
    print(
        f"trajectory RMSE {metrics['trajectory_rmse_avg_m']:.3f} m "
        f"(odometry {metrics['odometry_rmse_avg_m']:.3f} m)"
    )

    # 4. the map: each robot's markers against their true positions
    result = run.results["consensus"]
    for robot, (ids, positions) in enumerate(zip(result.object_ids, result.objects, strict=True)):
        error = np.linalg.norm(positions - dataset.object_position(ids), axis=1)
        print(
            f"  robot {robot}: {ids.size} of {dataset.object_ids.size} markers mapped, "
            f"error median {np.median(error):.3f} m, max {error.max():.3f} m"
        )
    print(f"wrote {args.out}/images, dataset and run")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
