"""Issue 14, section 2: a seeded property test. Hundreds of mutations of plan and pose files (names,
numbers, types, missing keys, broken text) go through the CLI in-process; each must end with exit 0 or
exactly one ``error:`` line, never a traceback, and must not create or change any file outside --out
(the whole surrounding tree is compared before and after every call)."""

from __future__ import annotations

import contextlib
import copy
import hashlib
import io
import json
import os
import random
import shutil
from pathlib import Path

import numpy as np
import pytest

from sparself.cli import main
from test_bad_input import make_scene, need, write_posed
from test_output_safety import TINY

# A pose value of 1e308 is a finite number, which the readers accept; arithmetic on such a capture (its
# scale, its camera distances) overflows to inf and numpy warns. What this test checks is the contract
# (exit 0 or one error line, nothing written outside --out), not numpy's arithmetic warnings.
pytestmark = pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")

SEED = 14
N_PLAN = 90  # mutated plans, each through `synthesize`
N_POSE = 160  # mutated pose files, each through `info` and `plan` (every 8th also `synthesize --scene`)


def snapshot(root: Path) -> dict:
    """Every entry under root: small files by content hash, big ones (the checkpoint) by size, mtime, inode."""
    out = {}
    for d, dirs, files in os.walk(root):
        for name in dirs + files:
            p = os.path.join(d, name)
            st = os.lstat(p)
            if os.path.islink(p):
                out[p] = "-> " + os.readlink(p)
            elif os.path.isdir(p):
                out[p] = "dir"
            elif st.st_size < 1 << 20:
                out[p] = hashlib.sha256(Path(p).read_bytes()).hexdigest()
            else:
                out[p] = (st.st_size, st.st_mtime_ns, st.st_ino)
    return out


@pytest.fixture(scope="module")
def sandbox(tmp_path_factory) -> dict:
    need("train", "synthesize")
    root = tmp_path_factory.mktemp("mut")
    scene = write_posed(root / "data" / "scene", make_scene(6), "llff")
    with contextlib.redirect_stderr(io.StringIO()) as err, contextlib.redirect_stdout(io.StringIO()):
        assert main([str(a) for a in ["train", scene, "--out", root / "run", *TINY, "-q"]]) == 0, err.getvalue()
        assert (
            main([str(a) for a in ["plan", scene, "--out", root / "plan.json", "--n-mid", "1", "--n-extra", "0", "-q"]])
            == 0
        ), err.getvalue()
    return {"root": root, "scene": scene, "run": root / "run", "plan": root / "plan.json"}


def call(sb: dict, argv: list, out: Path, what: str) -> int:
    """Run the CLI in-process; assert the contract; remove --out afterwards. Returns the exit code."""
    before = snapshot(sb["root"])
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main([str(a) for a in argv] + ["-q"])
    except BaseException as e:  # noqa: BLE001 - any escape is a traceback for the user
        raise AssertionError(f"{what}: {type(e).__name__}: {e}") from e
    text = err.getvalue()
    errors = [ln for ln in text.splitlines() if ": error: " in ln]
    assert "Traceback" not in text, f"{what}\n{text}"
    assert (code == 0 and not errors) or (code != 0 and len(errors) == 1), f"{what}: exit {code}\n{text}"
    if out.exists():
        shutil.rmtree(out) if out.is_dir() else out.unlink()
    after = snapshot(sb["root"])
    changed = sorted(set(after.items()) ^ set(before.items()))[:4]
    assert after == before, f"{what}: changed outside --out: {changed}"
    return code


# ---- mutations ----------------------------------------------------------------------------------------------


def hostile_name(rng: random.Random, root: Path) -> object:
    fixed = [
        "../../escaped.png",
        "../escaped.png",
        "..",
        ".",
        "",
        " ",
        str(root / "escaped.png"),
        "/escaped.png",
        "a/b.png",
        "a\\b.png",
        "C:escaped.png",
        "x\x00.png",
        "x\n.png",
        "x" * 300 + ".png",
        "00.png",
        "00.PNG",
        "novel.txt",
        "novel",
        ".png",
        "ok.png",
        "é.png",
        7,
        3.5,
        None,
        True,
        ["a.png"],
        {"a": 1},
    ]
    if rng.random() < 0.7:
        return rng.choice(fixed)
    return "".join(rng.choice("ab./\\.._-A\x01 ") for _ in range(rng.randint(1, 12))) + rng.choice([".png", ""])


def odd_value(rng: random.Random) -> object:
    return rng.choice(
        [
            float("nan"),
            float("inf"),
            -float("inf"),
            0,
            -1,
            1e308,
            -1e308,
            1e-320,
            10**400,
            2**63,
            -(2**70),
            "3",
            "x",
            True,
            False,
            None,
            [],
            {},
            [1, 2],
            [[1]],
            0.5,
            1e6,
        ]
    )


def mutate_json(rng: random.Random, doc: object, root: Path, names: tuple[str, ...]) -> object:
    """One random change somewhere in a JSON document: a name, a number, a type, a missing key."""
    doc = copy.deepcopy(doc)
    paths = []  # (container, key) pairs of every value

    def walk(x):
        items = x.items() if isinstance(x, dict) else enumerate(x) if isinstance(x, list) else []
        for k, v in items:
            paths.append((x, k))
            walk(v)

    walk(doc)
    if not paths or rng.random() < 0.03:
        return rng.choice([[], {}, "plan", 3, None, [doc]])
    kind = rng.random()
    named = [(c, k) for c, k in paths if k in names]
    if kind < 0.35 and named:
        c, k = rng.choice(named)
        c[k] = hostile_name(rng, root)
    elif kind < 0.7:
        nums = [(c, k) for c, k in paths if isinstance(c[k], (int, float))] or paths
        c, k = rng.choice(nums)
        c[k] = odd_value(rng)
    elif kind < 0.85:
        c, k = rng.choice(paths)
        c[k] = rng.choice([[], {}, "x", None, 1, [c[k]], {"v": c[k]}])
    else:
        c, k = rng.choice(paths)
        if isinstance(c, dict):
            del c[k]
        else:
            c.pop(k) if rng.random() < 0.5 else c.append(copy.deepcopy(c[k]))
    return doc


def dumps(rng: random.Random, doc: object) -> bytes:
    text = json.dumps(doc, indent=1)
    r = rng.random()
    if r < 0.04:
        return text[: rng.randint(0, len(text))].encode()  # truncated
    if r < 0.06:
        return b"\xff\xfe" + text.encode("utf-16-le")  # not UTF-8
    return text.encode()


def test_mutated_plans_through_synthesize(sandbox):
    rng = random.Random(SEED)
    base = json.loads(sandbox["plan"].read_text())
    plans, out = sandbox["root"] / "plans", sandbox["root"] / "outs" / "out"
    plans.mkdir(exist_ok=True)
    out.parent.mkdir(exist_ok=True)
    codes = []
    for k in range(N_PLAN):
        doc = base
        for _ in range(rng.randint(1, 3)):
            doc = mutate_json(rng, doc, sandbox["root"], ("name",))
        plan = plans / f"plan{k}.json"
        plan.write_bytes(dumps(rng, doc))
        codes.append(
            call(
                sandbox,
                ["synthesize", sandbox["run"], "--plan", plan, "--out", out],
                out,
                f"plan mutation {k}: {plan.read_bytes()[:400]!r}",
            )
        )
    assert 0.1 < codes.count(0) / len(codes) < 0.9, codes  # both kinds of outcome, in numbers
    assert not list(sandbox["root"].rglob("escaped*"))


def _mutate_transforms(rng, scene: Path, root: Path) -> None:
    js = scene / "transforms.json"
    doc = json.loads(js.read_text())
    for _ in range(rng.randint(1, 3)):
        doc = mutate_json(rng, doc, root, ("file_path",))
    js.write_bytes(dumps(rng, doc))


def _mutate_colmap(rng, scene: Path, root: Path) -> None:
    p = scene / "sparse" / "0" / rng.choice(["images.txt", "images.txt", "cameras.txt"])
    lines = p.read_text().splitlines()
    body = [i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#")]
    i = rng.choice(body)
    parts = lines[i].split()
    j = rng.randrange(len(parts))
    r = rng.random()
    if r < 0.4 and p.name == "images.txt" and len(parts) == 10:
        parts[9] = str(hostile_name(rng, root)).replace("\n", "_") or "_"
    elif r < 0.8:
        parts[j] = str(odd_value(rng)).replace(" ", "")
    else:
        del parts[j]
    lines[i] = " ".join(parts)
    p.write_text("\n".join(lines) + "\n")


def _mutate_llff(rng, scene: Path, root: Path) -> None:
    p = scene / "poses_bounds.npy"
    a = np.load(p)
    r = rng.random()
    if r < 0.6:
        a.flat[rng.randrange(a.size)] = rng.choice([np.nan, np.inf, 0.0, -1.0, 1e308, 1e-320, 5.0])
    elif r < 0.8:
        a = a[: rng.randint(0, len(a))] if rng.random() < 0.5 else a[:, : rng.randint(0, 17)]
    else:
        a = a.astype(rng.choice([np.int8, np.float16, np.complex64]))
    np.save(p, a)
    if rng.random() < 0.2:  # and an image renamed
        imgs = sorted((scene / "images").iterdir())
        victim = rng.choice(imgs)
        victim.rename(victim.with_name(victim.name.upper()))


def test_mutated_pose_files_through_info_plan_and_synthesize(sandbox):
    rng = random.Random(SEED + 1)
    formats = {"nerfstudio": _mutate_transforms, "colmap_text": _mutate_colmap, "llff": _mutate_llff}
    originals = {}
    for fmt in formats:
        originals[fmt] = write_posed(sandbox["root"] / "originals" / fmt, make_scene(6), fmt)
    work, out = sandbox["root"] / "work", sandbox["root"] / "outs" / "posed"
    out.parent.mkdir(exist_ok=True)
    for k in range(N_POSE):
        fmt = rng.choice(sorted(formats))
        scene = work / f"s{k}"
        shutil.copytree(originals[fmt], scene)
        formats[fmt](rng, scene, sandbox["root"])
        what = f"{fmt} mutation {k}"
        call(sandbox, ["info", scene], out, what)
        call(sandbox, ["plan", scene, "--out", out], out, what)
        if k % 8 == 0:
            call(
                sandbox,
                ["synthesize", sandbox["run"], "--plan", sandbox["plan"], "--scene", scene, "--out", out],
                out,
                what,
            )
        shutil.rmtree(scene)
    assert not list(sandbox["root"].rglob("escaped*"))
