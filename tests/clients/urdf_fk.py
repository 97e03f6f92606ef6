"""Forward kinematics of a URDF by yourdfpy (a URDF library the project did not write), for
tests/models.rs: reads {"urdf": path, "links": [...], "configs": [{joint: value}, ...]} as JSON
on stdin and prints, for each configuration, each link's 4 x 4 transform from the URDF's root
link (row-major lists) as JSON."""

import json
import sys

import yourdfpy


def main():
    job = json.load(sys.stdin)
    robot = yourdfpy.URDF.load(
        job["urdf"], build_scene_graph=True, load_meshes=False, build_collision_scene_graph=False
    )
    root = robot.base_link
    out = []
    for cfg in job["configs"]:
        robot.update_cfg(cfg)
        out.append(
            {link: robot.get_transform(frame_to=link, frame_from=root).tolist() for link in job["links"]}
        )
    json.dump({"root": root, "transforms": out}, sys.stdout)


if __name__ == "__main__":
    main()
