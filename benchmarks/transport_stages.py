"""How far a policy gets on Transport: per episode, the stages of robomimic's TwoArmTransport it reached.

    robomimic-venv/bin/python benchmarks/transport_stages.py --policy DIR [--seeds 3] [--max-steps 700]

Transport succeeds when the trash is in the trash bin and the payload (a hammer) in the target bin:
arm 0 lifts the lid off the start bin and picks the payload out of it, arm 1 bins the trash, then
takes the payload from arm 0 and lowers it into the target bin. For each of the first --seeds
held-out seeds this runs the policy with the zero ticket (`--base`: fresh noise from the seed's own
generator) up to --max-steps and reads the simulator: how far the lid moved, whether the trash is
in its bin, the payload's highest lift and how far it moved, whether it is in the target bin, the
step where the payload last moved, and where the handover stands at the end: arm 1's hand from the
payload (in the table's plane) and each gripper's opening (arm 0's, then arm 1's). It diagnoses a
policy whose success is near zero, where a success rate says nothing of where its episodes stop.
Prints a Markdown table.
"""

from __future__ import annotations

import argparse

import numpy as np

from goldenticket.policies import load_policy
from goldenticket.seeds import seeds_in
from goldenticket.tasks import get_task
from goldenticket.tasks.robomimic_experts import ARM_OBS

MOVED = 0.005  # m: the payload moved at a step when its position changed by more


def stages(policy, env, seed: int, max_steps: int, base: bool) -> dict:
    """One episode's stages, from the simulator's state."""
    obs, rng = env.reset(seed), np.random.default_rng(seed)
    sim, transport = env.robosuite_env.sim, env.robosuite_env.transport
    lid_geom = sim.model.geom_name2id(transport.lid.handle_geoms[0])
    lid_start, payload_start = sim.data.geom_xpos[lid_geom].copy(), transport.payload_pos.copy()
    lift, last_move, previous, step, success = 0.0, 0, payload_start, 0, False
    while step < max_steps and not success:
        noise = rng.standard_normal((1, *policy.noise_shape)) if base else np.zeros((1, *policy.noise_shape))
        for action in policy.act(obs[None].astype(np.float32), noise.astype(np.float32))[0]:
            obs, success, _ = env.step(action)
            step += 1
            payload = transport.payload_pos.copy()
            lift = max(lift, payload[2] - payload_start[2])
            if np.linalg.norm(payload - previous) > MOVED:
                last_move, previous = step, payload
            if success or step == max_steps:
                break
    return {"seed": seed, "steps": step, "success": success,
            "lid_moved": float(np.linalg.norm(sim.data.geom_xpos[lid_geom][:2] - lid_start[:2])),
            "trash_binned": bool(transport.trash_in_trash_bin), "payload_lift": float(lift),
            "payload_moved": float(np.linalg.norm(transport.payload_pos[:2] - payload_start[:2])),
            "payload_last_moved": last_move, "payload_binned": bool(transport.payload_in_target_bin),
            "arm1_from_payload": float(np.linalg.norm(obs[ARM_OBS:][:2] - transport.payload_pos[:2])),
            "openings": [float(obs[ARM_OBS * arm + 7] - obs[ARM_OBS * arm + 8]) for arm in (0, 1)]}


def markdown(rows: list[dict]) -> str:
    lines = ["| seed | steps | success | lid moved | trash binned | payload lift | payload moved | "
             "payload last moved at step | payload binned | arm 1 from payload | grippers open |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['seed']} | {r['steps']} | {r['success']} | {r['lid_moved']:.2f} m | "
              f"{r['trash_binned']} | {r['payload_lift']:.2f} m | {r['payload_moved']:.2f} m | "
              f"{r['payload_last_moved']} | {r['payload_binned']} | {r['arm1_from_payload']:.2f} m | "
              f"{r['openings'][0]:.3f}, {r['openings'][1]:.3f} m |" for r in rows]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", required=True,
                        help="a policy folder or bundled name, for robomimic/transport")
    parser.add_argument("--seeds", type=int, default=3, help="the first N held-out seeds")
    parser.add_argument("--max-steps", type=int, default=None, help="steps an episode may run (default: 700)")
    parser.add_argument("--base", action="store_true", help="fresh noise at every call, not the zero ticket")
    args = parser.parse_args()
    task = get_task("robomimic/transport")
    policy, env = load_policy(args.policy), task.make_env()
    rows = [stages(policy, env, seed, args.max_steps or task.max_steps, args.base)
            for seed in seeds_in("heldout", args.seeds)]
    print(markdown(rows), end="")


if __name__ == "__main__":
    main()
