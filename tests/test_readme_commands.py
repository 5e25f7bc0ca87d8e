"""README's commands match the code: eval.py / train.py overrides compose, modules' --help work, fast ones run.

Every ``python ...`` command of README.md and the docs/*.md pages it links (fenced code blocks, indented ones included, and inline code spans
in the prose) is collected with its line number. eval.py / train.py commands are composed with Hydra's
compose API (not run); ``python -m X`` commands must import and answer ``--help``, which must list every
``--option`` README gives them; a curated set of fast commands (each under ~10 s here) is run for real,
writing into a temporary folder. Hydra keys and group choices named in the prose (`dataset.drop_feet=true`,
`matching=feet_paper`) must exist too.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser

from tests.conftest import require_data_dir

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
DOCS = (README, *sorted((REPO / "docs").glob("*.md")))  # the front page and the reference pages it links
CONFIGS = REPO / "configs"
PLACEHOLDER = "PLACEHOLDER"  # stands for <run dir>, <date_time>, <.pth>, ... and `...`
RUN_TIMEOUT_S = 120  # generous: the first run after an install compiles numba's kernels (about 15 s)


@dataclass(frozen=True)
class ReadmeCommand:
    """One command of README.md: its first line number, its text (continuations joined) and where it stood."""

    line: int
    text: str
    where: str  # "block" (fenced code block) or "inline" (code span in the prose)
    doc: str = "README.md"  # the page, relative to the repository root

    def __str__(self) -> str:
        return f"{self.doc}:{self.line} ({self.where}): {self.text}"


def _strip_comment(line: str) -> str:
    """The line without a shell comment (a '#' at the start or after whitespace, outside quotes)."""
    quote = None
    for i, ch in enumerate(line):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i].rstrip()
    return line.rstrip()


def _python_parts(text: str) -> list[str]:
    """The parts of a shell line (split at &&, ||, ;) that start with python or torchrun."""
    parts = [p.strip() for p in re.split(r"&&|\|\||;", text)]
    return [p for p in parts if re.match(r"(python3?|torchrun)\s", p + " ")]


def _prose_spans() -> tuple[tuple[int, str], ...]:
    """(line, text) of every inline code span of README.md and docs/*.md (see _page_spans); the page is lost."""
    return tuple(span for page in DOCS for span in _page_spans(page))


@lru_cache(maxsize=8)
def _page_spans(page: Path) -> tuple[tuple[int, str], ...]:
    """(line, text) of every inline code span outside fenced blocks, whitespace (and line breaks) collapsed."""
    prose, in_block = [], False
    for number, raw in enumerate(page.read_text(encoding="utf-8").splitlines(), start=1):
        if raw.strip().startswith("```"):
            in_block = not in_block
        elif not in_block:
            prose.append((number, raw))
    text = "\n".join(raw for _, raw in prose)
    starts = [0]
    for _, raw in prose:
        starts.append(starts[-1] + len(raw) + 1)
    spans = []
    for match in re.finditer(r"(?<!`)`([^`]+)`(?!`)", text):
        line = prose[max(i for i, start in enumerate(starts) if start <= match.start())][0]
        spans.append((line, " ".join(match.group(1).split())))
    return tuple(spans)


@lru_cache(maxsize=1)
def readme_commands() -> tuple[ReadmeCommand, ...]:
    """Every python/torchrun command of README.md and docs/*.md (bash blocks and inline code spans), in order."""
    return tuple(c for page in DOCS for c in _page_commands(page))


def _page_commands(page: Path) -> tuple[ReadmeCommand, ...]:
    """Every python/torchrun command in one page's bash blocks and inline code spans, in order."""
    doc = str(page.relative_to(REPO))
    lines = page.read_text(encoding="utf-8").splitlines()
    commands: list[ReadmeCommand] = []
    in_block, is_shell = False, False
    pending, pending_line = "", 0
    for number, raw in enumerate(lines, start=1):
        stripped = raw.strip()
        if stripped.startswith("```"):
            in_block = not in_block
            is_shell = in_block and stripped[3:].strip() in ("bash", "sh", "shell", "console", "")
            pending = ""
            continue
        if not in_block or not is_shell:
            continue
        code = _strip_comment(raw)
        if not pending:
            pending_line = number
        if code.endswith("\\"):
            pending += code[:-1].strip() + " "
            continue
        full, pending = (pending + code.strip()).strip(), ""
        commands += [ReadmeCommand(pending_line, part, "block", doc) for part in _python_parts(full)]
    commands += [
        ReadmeCommand(line, span, "inline", doc)
        for line, span in _page_spans(page)
        if re.match(r"(python3?|torchrun)\s", span + " ")
    ]
    return tuple(sorted(set(commands), key=lambda c: (c.line, c.text)))


def _tokens(command: ReadmeCommand) -> list[str]:
    """Shell words of the command, placeholders (<...>, ...) as PLACEHOLDER and optional [...] unwrapped."""
    text = re.sub(r"<[^<>]*>", PLACEHOLDER, command.text)
    try:
        words = shlex.split(text)
    except ValueError as error:
        pytest.fail(f"{command}\ncannot be split into shell words: {error}")
    words = [w[1:-1] if w.startswith("[") and w.endswith("]") and "=" in w else w for w in words]
    return [w.replace("...", PLACEHOLDER) for w in words if w != "..."]


def _script_and_args(command: ReadmeCommand) -> tuple[str, list[str]]:
    """('eval.py', args), ('train.py', args), ('-m module', args) or ('other', words) of a command."""
    words = _tokens(command)
    if words[0] == "torchrun":
        scripts = [i for i, w in enumerate(words) if w.endswith(".py")]
        return (words[scripts[0]], words[scripts[0] + 1 :]) if scripts else ("other", words)
    if len(words) >= 3 and words[1] == "-m":
        return f"-m {words[2]}", words[3:]
    if len(words) >= 2 and words[1].endswith(".py"):
        return words[1], words[2:]
    return "other", words


def _hydra_commands() -> list[ReadmeCommand]:
    """README's eval.py and train.py commands."""
    return [c for c in readme_commands() if _script_and_args(c)[0] in ("eval.py", "train.py")]


def _module_names() -> list[str]:
    """Every module README runs with python -m, in order of first mention."""
    names = [_script_and_args(c)[0][3:] for c in readme_commands() if _script_and_args(c)[0].startswith("-m ")]
    return list(dict.fromkeys(names))


def test_readme_commands_are_found_and_every_script_exists() -> None:
    """The parser sees README's commands (a broken parser would pass every test vacuously); scripts exist."""
    commands = readme_commands()
    texts = [c.text for c in commands]
    assert len(_hydra_commands()) >= 20 and len(_module_names()) >= 8, texts
    assert "python eval.py dataset.noise_px=0 dataset.occlusion=false" in texts
    joined = (
        "python eval.py dataset=files dataset.cameras=examples/own_rig/cameras.json "
        "dataset.poses2d=examples/own_rig/poses2d.json"
    )
    assert joined in texts, "continuation lines are not joined"
    assert any(c.where == "block" and c.text.startswith("python -m data.geometry.check_rig") for c in commands)
    for command in commands:
        script, _ = _script_and_args(command)
        assert script != "other", f"{command}\nneither a script nor python -m MODULE"
        if not script.startswith("-m "):
            assert (REPO / script).is_file(), f"{command}\n{script} does not exist in the repository"


def _split_placeholders(overrides: list[str]) -> tuple[list[str], list[str]]:
    """(overrides to compose, config groups whose value is a placeholder); placeholder values of keys stay."""
    compose_these, groups = [], []
    for override in overrides:
        key, _, value = override.partition("=")
        if PLACEHOLDER in value and "." not in key and (CONFIGS / key.lstrip("+~")).is_dir():
            groups.append(key.lstrip("+~"))  # a config group's choice cannot be composed without a value
        else:
            compose_these.append(override)
    return compose_these, groups


def _expand_alternatives(overrides: list[str]) -> list[list[str]]:
    """One override list per README alternative 'key=a|b' (each composed); a single list when there is none."""
    for i, override in enumerate(overrides):
        key, _, value = override.partition("=")
        if "|" in value and not value.startswith(("'", '"')):
            return [
                alt
                for choice in value.split("|")
                for alt in _expand_alternatives([*overrides[:i], f"{key}={choice}", *overrides[i + 1 :]])
            ]
    return [overrides]


def _sweep_variants(overrides: list[str]) -> list[list[str]]:
    """Plain override lists for a -m command: each choice of each sweep override, the others at their first."""
    parsed = OverridesParser.create().parse_overrides(overrides)
    choices = [
        [f"{o.get_key_element()}={v}" for v in o.sweep_string_iterator()] if o.is_sweep_override() else [o.input_line]
        for o in parsed
    ]
    firsts = [c[0] for c in choices]
    variants = [firsts]
    for i, options in enumerate(choices):
        variants += [[*firsts[:i], option, *firsts[i + 1 :]] for option in options[1:]]
    return variants


def _compose(config_name: str, overrides: list[str], hydra_config: bool = False):
    """Hydra's composed config for these overrides (nothing is run)."""
    with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
        return compose(config_name=config_name, overrides=overrides, return_hydra_config=hydra_config)


def _compose_problems(command: ReadmeCommand) -> list[str]:
    """What does not compose in an eval.py / train.py command (empty when every key and group exists)."""
    script, args = _script_and_args(command)
    config_name = script.removesuffix(".py")
    multirun = "-m" in args or "--multirun" in args
    overrides = [a for a in args if a not in ("-m", "--multirun")]
    problems = [f"unexpected option {a!r} among the overrides" for a in overrides if a.startswith("-")]
    overrides, placeholder_groups = _split_placeholders(overrides)
    problems += [f"no config group {g!r} in configs/" for g in placeholder_groups if not (CONFIGS / g).is_dir()]
    variants = [v for alt in _expand_alternatives(overrides) for v in (_sweep_variants(alt) if multirun else [alt])]
    for variant in variants:
        try:
            cfg = _compose(config_name, variant, hydra_config=multirun)
        except Exception as error:  # noqa: BLE001 - any composition error is a README/code mismatch
            problems.append(
                f"{variant} does not compose with configs/{config_name}.yaml: {type(error).__name__}: {error}"
            )
            continue
        if multirun:  # the sweep an experiment defines (hydra.sweeper.params): each of its choices
            params = cfg.hydra.sweeper.get("params") or {}
            swept = [f"{key}={value}" for key, value in params.items()]
            for sweep_variant in _sweep_variants(swept) if swept else []:
                try:
                    _compose(config_name, [*variant, *sweep_variant])
                except Exception as error:  # noqa: BLE001
                    problems.append(
                        f"its sweep {swept} does not compose ({sweep_variant}): {type(error).__name__}: {error}"
                    )
    return problems


@pytest.mark.parametrize("command", _hydra_commands(), ids=lambda c: f"L{c.line}")
def test_hydra_command_overrides_compose(command: ReadmeCommand) -> None:
    """Every key and config group README passes to eval.py / train.py exists (sweeps: every choice)."""
    problems = _compose_problems(command)
    assert not problems, f"{command}\n" + "\n".join(problems)


@pytest.mark.parametrize(
    "text",
    [
        "python eval.py dataset.no_such_key=1",
        "python eval.py matching=no_such_matcher",
        "python eval.py reconstruction=... no_such_group=<x>",
        "python train.py -m loss.mu=0,0.5 trainer.no_such_key=1,2",
        "python train.py resume=<run dir>/last.ckpt trainer.epoch=200",
    ],
)
def test_the_compose_check_catches_a_missing_key(text: str) -> None:
    """The check is not vacuous: a key or group that does not exist is reported."""
    assert _compose_problems(ReadmeCommand(0, text, "block"))


def _run(words: list[str], timeout: float = RUN_TIMEOUT_S) -> tuple[subprocess.CompletedProcess, float]:
    """The command run from the repository root with this interpreter, and its wall time in seconds."""
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, *words],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    return proc, time.perf_counter() - start


@lru_cache(maxsize=None)
def _module_help(module: str) -> tuple[int, str]:
    """Exit status and output of ``python -m module --help``."""
    proc, _ = _run(["-m", module, "--help"])
    return proc.returncode, proc.stdout + proc.stderr


@pytest.mark.parametrize("module", _module_names())
def test_readme_module_imports_and_answers_help(module: str) -> None:
    """Every module README runs with python -m exists, its argparse works and lists README's --options."""
    returncode, output = _module_help(module)
    users = [c for c in readme_commands() if _script_and_args(c)[0] == f"-m {module}"]
    assert returncode == 0 and "usage" in output.lower(), f"{users[0]}\n`python -m {module} --help` failed:\n{output}"
    for command in users:
        for option in re.findall(r"(?<!\S)(--[A-Za-z][\w-]*)", " ".join(_script_and_args(command)[1])):
            assert option in output, f"{command}\n{option} is not an option of `python -m {module}`:\n{output}"


def _readme_command(text: str) -> ReadmeCommand:
    """The README command with this exact text (the curated list must follow README)."""
    found = [c for c in readme_commands() if c.text == text]
    assert found, f"README.md / docs no longer hold the command `{text}`: update the curated list in this test"
    return found[0]


SHARED = "../shared/data"
# (README command, extra words to keep its outputs in the temporary folder, needs ../shared/data); measured
# 1.7-4 s each here once numba's cache is warm; the other README commands take minutes or need downloads
FAST_COMMANDS = [
    ("python eval.py dataset.noise_px=0 dataset.occlusion=false", ["progress=false", "hydra.run.dir={tmp}"], False),
    ("python eval.py progress=false", ["hydra.run.dir={tmp}"], False),
    (
        "python eval.py dataset=files dataset.cameras=examples/own_rig/cameras.json "
        "dataset.poses2d=examples/own_rig/poses2d.json",
        ["progress=false", "hydra.run.dir={tmp}"],
        False,
    ),
    ("python eval.py dataset=panoptic", ["progress=false", "hydra.run.dir={tmp}"], True),
    (
        "python eval.py dataset.rig=../shared/data/wildtrack dataset.rig_format=wildtrack dataset.area='[-3,9,-9,27]'",
        ["progress=false", "hydra.run.dir={tmp}"],
        True,
    ),
    ("python eval.py dataset=shelf", ["progress=false", "hydra.run.dir={tmp}"], True),
    ("python -m data.geometry.check_rig cameras.json poses2d.json", [], False),
]


def _fast_words(text: str, extra: list[str], tmp: Path) -> list[str]:
    """The words after ``python`` of a curated README command, outputs redirected into tmp."""
    words = shlex.split(_readme_command(text).text)[1:]
    if words[:2] == ["-m", "data.geometry.check_rig"]:  # README's file names, as in examples/own_rig
        words = [*words[:2], "examples/own_rig/cameras.json", "examples/own_rig/poses2d.json"]
    return [*words, *(e.format(tmp=tmp) for e in extra)]


@pytest.mark.parametrize("text, extra, needs_shared", FAST_COMMANDS, ids=[text for text, _, _ in FAST_COMMANDS])
def test_fast_readme_command_runs(text: str, extra: list[str], needs_shared: bool, tmp_path: Path) -> None:
    """A fast README command runs to exit status 0 from the repository root, outputs in a temporary folder."""
    if needs_shared:
        require_data_dir(REPO / SHARED)
    words = _fast_words(text, extra, tmp_path)
    proc, seconds = _run(words)
    command = _readme_command(text)
    assert proc.returncode == 0, f"{command}\nexited {proc.returncode} in {seconds:.1f} s:\n{proc.stderr[-3000:]}"
    if words[0] == "eval.py":
        assert list(tmp_path.rglob("metrics.json")), f"{command}\nwrote no metrics.json into {tmp_path}"


def test_readme_reconstruction_sweeps_and_their_gather_sweep_command_run(tmp_path: Path) -> None:
    """README's two reconstruction sweeps run, and its gather_sweep command (its metrics) reads them."""
    gather = _readme_command(
        "python -m benchmarks.gather_sweep multirun/reconstruction_ablation/<a> multirun/prior_weight/<b> "
        "--metrics mpjpe_mm,pcp_average,reprojection_mean_px,reprojection_min_px,reprojection_max_px,"
        "reprojection_var_px2,reconstruction_ms"
    )
    for experiment in ("reconstruction_ablation", "prior_weight"):
        sweep = _readme_command(f"python eval.py -m +experiment={experiment}")
        words = [*shlex.split(sweep.text)[1:], "progress=false", f"hydra.sweep.dir={tmp_path / experiment}"]
        proc, seconds = _run(words)
        assert proc.returncode == 0, f"{sweep}\nexited {proc.returncode} in {seconds:.1f} s:\n{proc.stderr[-3000:]}"
    words = shlex.split(gather.text.replace("multirun/", f"{tmp_path}/").replace("/<a>", "").replace("/<b>", ""))
    proc, _ = _run(words[1:])
    assert proc.returncode == 0, f"{gather}\nexited {proc.returncode}:\n{proc.stderr[-3000:]}"
    metrics = words[words.index("--metrics") + 1].split(",")
    rows = [
        [cell.strip() for cell in row.strip().strip("|").split("|")]
        for row in proc.stdout.splitlines()
        if row.startswith("|") and not row.startswith("|-")
    ]
    runs = len(list(tmp_path.glob("*/*/metrics.json")))
    assert runs > 0 and len(rows) == 1 + runs, f"{gather}\nnot one row per run of the two sweeps:\n{proc.stdout}"
    for column, metric in enumerate(metrics, start=len(rows[0]) - len(metrics)):
        assert any(row[column] != "-" for row in rows[1:]), (
            f"{gather}\nmetric {metric!r} is in no run's metrics.json:\n{proc.stdout}"
        )


CONFIG_GROUPS = sorted(p.name for p in CONFIGS.iterdir() if p.is_dir())


def _key_paths(node, prefix: str = "") -> set[str]:
    """Every dotted key path of an OmegaConf node (interpolations left unresolved)."""
    from omegaconf import DictConfig

    paths: set[str] = set()
    if isinstance(node, DictConfig):
        for key in node.keys():
            path = f"{prefix}{key}"
            paths.add(path)
            paths |= _key_paths(node._get_node(key), f"{path}.")
    return paths


@lru_cache(maxsize=1)
def _known_keys() -> frozenset[str]:
    """Every key of eval.yaml and train.yaml under any one choice of each config group or experiment."""
    keys: set[str] = set()
    for config_name in ("eval", "train"):
        variants: list[list[str]] = [[]]
        for group in CONFIG_GROUPS:
            prefix = "+" if group == "experiment" else ""
            variants += [[f"{prefix}{group}={choice.stem}"] for choice in sorted((CONFIGS / group).glob("*.yaml"))]
        variants += [["hydra/launcher=joblib"], ["hydra/launcher=submitit_slurm"]]  # the plugins' keys (docs)
        for variant in variants:
            try:
                keys |= _key_paths(_compose(config_name, variant, hydra_config=True))
            except Exception:  # noqa: BLE001 - a group the other entry point does not have
                continue
    return frozenset(keys)


def _is_python_object(dotted: str) -> bool:
    """Whether a dotted name is an importable module or an attribute of one (data.keypoints.coco23_to_shelf14)."""
    import importlib

    parts = dotted.split(".")
    for split in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:split]))
        except ImportError:
            continue
        for attribute in parts[split:]:
            if not hasattr(obj, attribute):
                return False
            obj = getattr(obj, attribute)
        return True
    return False


def _prose_config_mentions() -> list[tuple[int, str, str]]:
    """(line, code span, key or group=choice) for each Hydra key or group choice named in README's prose spans."""
    roots = {key.split(".")[0] for key in _known_keys()} | set(CONFIG_GROUPS)
    mentions = []
    for line, span in _prose_spans():
        if span.startswith(("python", "torchrun")):
            continue  # commands: composed above
        words = re.sub(r"<[^<>]*>", PLACEHOLDER, span).split()
        if not all(re.fullmatch(r"\+?[a-z_]\w*(\.\w+)*(=\S*)?", w) for w in words):
            continue
        for word in words:
            key, has_value, value = word.lstrip("+").partition("=")
            if key.split(".")[0] not in roots or (not has_value and "." not in key):
                continue  # a short form in the prose (robust=cauchy), a file name, a plain word
            if has_value and key in CONFIG_GROUPS and PLACEHOLDER not in value and "..." not in value:
                mentions.append((line, span, f"{key}={value}"))
            else:
                mentions.append((line, span, key))
    return mentions


def test_config_keys_named_in_readme_prose_exist() -> None:
    """Every Hydra key (`evaluation.max_dist_m`, `dataset.drop_feet=true`) and group choice in README's prose exists."""
    mentions = _prose_config_mentions()
    assert len(mentions) >= 30, mentions
    known = _known_keys()
    assert {"evaluation.max_dist_m", "matching.k2", "trainer.epochs", "hydra.run.dir"} <= known  # not vacuous
    assert "evaluation.max_dist" not in known and not _is_python_object("data.keypoints.no_such_name")
    missing = []
    for line, span, mention in mentions:
        key, _, choice = mention.partition("=")
        if choice:
            ok = (CONFIGS / key / f"{choice}.yaml").is_file()
        else:
            ok = key in known or _is_python_object(key)
        if not ok:
            missing.append(
                f"README.md or docs, line {line}: `{span}`: {mention!r} is neither a config key nor a config choice"
                if not choice
                else f"README.md or docs, line {line}: `{span}`: no configs/{key}/{choice}.yaml"
            )
    assert not missing, "\n".join(missing)
