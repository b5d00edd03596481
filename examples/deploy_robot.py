"""A simulated robot on `home`, driven by an exported policy alone.

    tpo train --map home --out runs/home
    tpo export runs/home --format npz --out home-policy.npz
    python examples/deploy_robot.py home-policy.npz [MAP]   # MAP: a map file, if not bundled

The robot's side (`Robot`) imports only NumPy and `tpo.deploy`: position →
observation → action, as on a real robot. The world around it (`World`: walls,
moves, the goal) stands in for the hardware and reads the map with `tpo.envs`.
"""

from __future__ import annotations

import sys

import numpy as np

from tpo.deploy import load_policy


class Robot:
    """The robot's controller: the exported policy and its observer, nothing else."""

    def __init__(self, path: str) -> None:
        self.policy = load_policy(path)
        if self.policy.meta["observation"]["kind"] == "continuous":
            sys.exit("this example drives a grid robot; export a grid run")

    def decide(self, cell: tuple[int, int]) -> int:
        return int(self.policy.act(self.policy.observer.observe(cell=cell)))


class World:
    """The simulated home: the robot moves a cell per step unless a wall is in the way."""

    MOVES = np.array([(-1, 0), (1, 0), (0, -1), (0, 1)])  # up, down, left, right

    def __init__(self, map_name: str, sha256: str) -> None:
        from tpo.envs import load_map
        from tpo.errors import MapError

        try:
            self.map = load_map(map_name)
        except MapError as err:
            sys.exit(f"{err} (give the policy's map file as the second argument)")
        if self.map.sha256() != sha256:
            sys.exit(f"the policy was trained on another map than {map_name}")

    def move(self, cell: tuple[int, int], action: int) -> tuple[int, int]:
        r, c = np.asarray(cell) + self.MOVES[action]
        h, w = self.map.shape
        blocked = not (0 <= r < h and 0 <= c < w) or self.map.walls[r, c]
        return cell if blocked else (int(r), int(c))


def main(path: str, map_name: str | None = None) -> None:
    robot = Robot(path)
    trained_on = robot.policy.meta["map"]
    world = World(map_name or trained_on["name"], trained_on["sha256"])
    cell = tuple(int(v) for v in world.map.start)
    names = robot.policy.meta["action"]["meanings"]
    print(f"policy for {robot.policy.meta['dag']} at slack {robot.policy.meta['slack']}; "
          f"start {cell}, goal {tuple(world.map.goal)}")
    for step in range(world.map.max_steps):
        action = robot.decide(cell)
        cell = world.move(cell, action)
        in_monitor = bool(world.map.monitor_mask[cell])
        print(f"step {step + 1:3d}: {names[action]:<5} -> {cell}"
              f"{'  (monitoring)' if in_monitor else ''}")
        if cell == tuple(world.map.goal):
            print(f"goal reached in {step + 1} steps")
            return
    print(f"goal not reached in {world.map.max_steps} steps")


if __name__ == "__main__":
    main(*sys.argv[1:3]) if len(sys.argv) > 1 else main("home-policy.npz")
