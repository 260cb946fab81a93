"""Ray scale-out: benchmark episodes as Ray tasks and PPO collectors as Ray actors, on a local
Ray instance, give the same results as the process-pool path and a usable checkpoint."""

import contextlib
import ipaddress
import json
import os
from pathlib import Path

import ray  # noqa: F401  (the test extra installs it: a missing Ray fails here instead of skipping)
import torch

from train.__main__ import main

TINY = str(Path(__file__).parent / "benchmark" / "tiny_suite.yaml")


def _overall(out: Path) -> dict:
    return json.loads((out / "results.json").read_text())["agents"]["zoo:keep-lane"]["scores"]["overall"]


def test_benchmark_on_ray_scores_the_same_as_the_process_pool(tmp_path):
    base = ["benchmark", "--suite", TINY, "--episodes", "1", "--agent", "zoo:keep-lane", "--quiet"]
    assert main([*base, "--workers", "2", "--out", str(tmp_path / "pool")]) == 0
    assert main([*base, "--ray-address", "local", "--out", str(tmp_path / "ray")]) == 0
    assert len(list((tmp_path / "ray" / "logs" / "zoo_keep-lane").rglob("*.npz"))) == 2  # one episode per scenario
    assert len(list((tmp_path / "ray" / "logs").rglob("*.npz"))) == 3 * 2  # with the other reference agents
    pool, on_ray = _overall(tmp_path / "pool"), _overall(tmp_path / "ray")
    assert pool and on_ray == pool


def test_ppo_with_ray_collectors_writes_a_final_checkpoint(tmp_path):
    """On the batched backend (per_env builds the same env): the two collectors' shares hold one
    and two learning agents, padded to one batch shape."""
    out = tmp_path / "run"
    args = ["ppo", "--task", "platoon", "--backend", "batched", "--total-steps", "256", "--frames-per-batch", "128",
            "--minibatch-size", "64", "--epochs", "1", "--envs", "2", "--workers", "2", "--eval-episodes", "0",
            "--ray-address", "local", "--out-dir", str(out), "--quiet"]  # fmt: skip
    assert main(args) == 0
    blob = torch.load(out / "final.pt", weights_only=True)
    assert blob["step"] == 256 and blob["config"]["ray_address"] == "local" and blob["config"]["backend"] == "batched"


def test_ray_collectors_play_the_copies_episodes_of_a_run_without_ray():
    """The one seeding rule across collectors: each collector's env numbers its copies as in the
    whole batch, so copy i starts at the same seed (and gives the same first observation) as in
    the env training builds without Ray; padding slots stay zero and invalid."""
    from train.config import load_config
    from train.ppo import make_env, ray_env_factories

    cfg = load_config("platoon", overrides={"envs": 4, "workers": 2, "ray_address": "local"})
    whole = make_env(cfg.model_copy(update={"workers": 1}))
    shares = [factory() for factory in ray_env_factories(cfg)]
    try:
        first = whole.reset()
        slot = {key: j for j, key in enumerate(whole.base_env.slots)}
        for w, env in enumerate(shares):
            assert env.batch_size == torch.Size([3])  # copies (0, 2): 1 + 1 agents, padded; (1, 3): 2 + 1
            td = env.reset()
            own = env.base_env.driving
            assert own.copy_ids == list(range(w, 4, 2))
            for j, (copy, agent) in enumerate(env.base_env.slots):
                if copy < 0:
                    assert not td["valid"][j].any() and not td["observation", "ego"][j].any()
                    continue
                global_slot = slot[(own.copy_ids[copy], agent)]
                assert torch.equal(td["observation", "ego"][j], first["observation", "ego"][global_slot])
        assert any((-1, "") in env.base_env.slots for env in shares)
    finally:
        whole.close()
        for env in shares:
            env.close()


def test_ray_collectors_need_envs_divisible_by_workers(tmp_path, capsys):
    args = ["ppo", "--task", "platoon", "--envs", "3", "--workers", "2", "--ray-address", "local",
            "--out-dir", str(tmp_path), "--quiet"]  # fmt: skip
    assert main(args) == 2
    assert "must be multiples of workers" in capsys.readouterr().err


def _listening_addresses(pids: set[int]) -> list[ipaddress.IPv4Address | ipaddress.IPv6Address]:
    """Local addresses of the TCP sockets the processes ``pids`` listen on (Linux /proc)."""
    inodes = set()
    for pid in pids:
        with contextlib.suppress(OSError):
            for fd in os.listdir(f"/proc/{pid}/fd"):
                with contextlib.suppress(OSError):
                    link = os.readlink(f"/proc/{pid}/fd/{fd}")
                    if link.startswith("socket:["):
                        inodes.add(link[len("socket:[") : -1])
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with contextlib.suppress(OSError), open(table) as f:
            for row in f.read().splitlines()[1:]:
                cols = row.split()
                if cols[3] != "0A" or cols[9] not in inodes:  # 0A: LISTEN
                    continue
                raw = bytes.fromhex(cols[1].split(":")[0])  # 32-bit words in host (little) order
                found.append(ipaddress.ip_address(b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))))
    return found


def _descendants(pid: int) -> set[int]:
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            with contextlib.suppress(OSError):
                stat = Path(f"/proc/{entry}/stat").read_text()
                children.setdefault(int(stat.rpartition(")")[2].split()[1]), []).append(int(entry))
    found, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def test_local_ray_listens_on_loopback_only():
    from smarts.ray_session import ray_session

    with ray_session("local", num_cpus=1) as session:
        assert [n["NodeManagerAddress"] for n in session.nodes()] == ["127.0.0.1"]
        assert session.get_runtime_context().gcs_address.startswith("127.0.0.1:")
        assert session.get(session.remote(lambda: session.util.get_node_ip_address()).remote()) == "127.0.0.1"
        if Path("/proc/net/tcp").exists():
            addresses = _listening_addresses(_descendants(os.getpid()) | {os.getpid()})
            assert addresses, "found none of Ray's listening sockets"
            mapped = [getattr(a, "ipv4_mapped", None) or a for a in addresses]
            assert all(a.is_loopback for a in mapped), addresses


def test_ray_training_listens_on_loopback_only():
    """The learner and its Ray collectors, built as ``--ray-address local`` builds them and after
    a batch and a weight update, listen on loopback only (weights travel through Ray's own
    loopback channels, no other server is opened)."""
    import contextlib as _contextlib

    from train.config import load_config
    from train.ppo import open_envs
    from train.run import BatchPlan

    cfg = load_config(
        "platoon",
        overrides={"envs": 2, "workers": 2, "ray_address": "local", "frames_per_batch": 64, "minibatch_size": 64},
    )
    with _contextlib.ExitStack() as scale_out:
        envs = open_envs(cfg, None, scale_out)
        plan = BatchPlan.of(128, cfg.frames_per_batch, envs.slots, whole=True)
        collection = envs.collection(cfg, plan, torch.device("cpu"))
        scale_out.callback(collection.close)
        import ray
        from tensordict import TensorDict

        def remote_weights() -> list[dict]:
            return [ray.get(a.state_dict.remote())["policy_state_dict"] for a in collection.collector.remote_collectors]

        def same(remote: dict) -> bool:
            local = dict(TensorDict.from_module(collection.actor).data.flatten_keys(".").items())
            return remote.keys() == local.keys() and all(torch.equal(v, local[k]) for k, v in remote.items())

        assert all(same(w) for w in remote_weights())  # the actors start from the learner's weights
        with torch.no_grad():
            for p in envs.parts.actor_net.parameters():
                p.add_(0.5)
        assert not any(same(w) for w in remote_weights())
        collection.sync(envs.parts)
        assert all(same(w) for w in remote_weights())  # an update reaches every actor
        assert collection.take() is not None
        addresses = _listening_addresses(_descendants(os.getpid()) | {os.getpid()})
        assert addresses, "found none of Ray's listening sockets"
        mapped = [getattr(a, "ipv4_mapped", None) or a for a in addresses]
        assert all(a.is_loopback for a in mapped), addresses
