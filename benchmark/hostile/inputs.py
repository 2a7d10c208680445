"""Attacks on the files a command names: model configs (``model info``), instruction scripts
(``run --instructions``) and event programs with their ``--states`` (``event-program``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from storyteller.benchmark.hostile.harness import (
    BIDI,
    CLEAN_PROGRAM,
    Attack,
    Box,
    Expect,
    Spec,
    deep_json,
    refused_for,
    registrar,
)

ATTACKS: list[Attack] = []
attack = registrar(ATTACKS)


def model_info(path: Path) -> Spec:
    return Spec(["model", "info", "--config", str(path)], "model info", "bad")


@attack("config", "backoff_base_s = inf")
def _config_inf(box: Box) -> Spec:
    return model_info(box.file("inf.toml", '[llm]\nmodel = "openai/x"\n[llm.retry]\nbackoff_base_s = inf\n'))


@attack("config", "arrays nested 50,000 deep")
def _config_deep(box: Box) -> Spec:
    return model_info(box.file("deep.toml", "x = " + "[" * 50_000 + "]" * 50_000 + "\n"))


@attack("config", "not UTF-8")
def _config_bytes(box: Box) -> Spec:
    return model_info(box.file("bytes.toml", b'[llm]\nmodel = "\xff\xfe"\n'))


@attack("config", "model and api_base with escapes and bidi")
def _config_text(box: Box) -> Spec:
    text = '[llm]\nmodel = "openai/x\\u001b[31m\\u202e"\napi_base = "http://a\\u0007\\u2028b"\n'
    return Spec(["model", "info", "--config", str(box.file("text.toml", text))], "model info", "either")


@attack("config", "FIFO config")
def _config_fifo(box: Box) -> Spec:
    return model_info(box.fifo(box.root / "fifo.toml"))


@attack("config", "timeout_s = 1e308, max_attempts of 5,000 digits, backoff_max_s = -1")
def _config_numbers(box: Box) -> Spec:
    return model_info(box.file("nums.toml", '[llm]\nmodel = "openai/x"\ntimeout_s = 1e308\n[llm.retry]\n'
                                            f"max_attempts = {'9' * 5000}\nbackoff_max_s = -1\n"))


def script_run(box: Box, path: Path) -> Spec:
    out = box.root / "o"
    return Spec(["run", "home", "--instructions", str(path), "--out", str(out), "--no-interactive", "--no-live"],
                "run", "bad", writable=(out,))


@attack("script", "instruction time of 400 nines")
def _script_nines(box: Box) -> Spec:
    return script_run(box, box.file("nines.txt", "9" * 400 + ":00 everyone sits\n"))


@attack("script", "a 30 MB line")
def _script_long(box: Box) -> Spec:
    return script_run(box, box.file("long.txt", "00:01 " + "a" * 30_000_000 + "\n"))


@attack("script", "NUL and bytes that are not UTF-8")
def _script_bytes(box: Box) -> Spec:
    return script_run(box, box.file("bytes.txt", b"00:01 go\x00\xff\xfe\n"))


@attack("script", "FIFO script")
def _script_fifo(box: Box) -> Spec:
    return script_run(box, box.fifo(box.root / "fifo.txt"))


@attack("script", "times with Arabic-Indic digits, negative and past the run")
def _script_digits(box: Box) -> Spec:
    return script_run(box, box.file("digits.txt", "\u0660\u0660:\u0660\u0661 sit\n-00:05 stand\n99999999:00 go\n"))


def program_run(path: Path, expect: Expect = "bad") -> Spec:
    return Spec(["event-program", "home", "--program", str(path)], "event-program", expect)


@attack("program", "a 400 MB sparse program file")
def _program_sparse(box: Box) -> Spec:
    path = box.root / "sparse.py"
    with open(path, "wb") as f:
        f.truncate(400 << 20)
    return program_run(path)


@attack("program", "FIFO program")
def _program_fifo(box: Box) -> Spec:
    return program_run(box.fifo(box.root / "fifo.py"))


@attack("program", "a character name and action with escapes and bidi")
def _program_text(box: Box) -> Spec:
    text = ('def parse_event():\n    a = get_character("Zoe\\u202e\\x1b[31m")\n'
            '    a.set_position(get_area_to_sit_on("couch_1"))\n    a.set_target_action("sit\\u2066\\x07")\n')
    return program_run(box.file("text.py", text), "program")


@attack("program", "--states nested 100,000 deep")
def _program_states(box: Box) -> Spec:
    prog = box.file("ok.py", CLEAN_PROGRAM)
    spec = program_run(prog)
    spec.argv += ["--states", str(box.file("states.json", deep_json(100_000)))]
    return spec


@attack("program", "100,000 nested parentheses")
def _program_parens(box: Box) -> Spec:
    text = "def parse_event():\n    x = " + "(" * 100_000 + "1" + ")" * 100_000 + "\n"
    return program_run(box.file("parens.py", text), "program")


@attack("program", "a 5 MB string literal and 50,000 statements")
def _program_big(box: Box) -> Spec:
    text = "def parse_event():\n    s = '" + "a" * 5_000_000 + "'\n" + "    x = 1\n" * 50_000
    return program_run(box.file("big.py", text), "program")


@attack("program", "--states with 10,000 characters named with bidi and 100 KB names")
def _program_states_names(box: Box) -> Spec:
    """A world view (``characters``) valid but for its names: the program's unknown character is
    answered with the names, which must be shown escaped. (A reference ``current_states`` was a
    mapping, not its list, and one of 10,001 keys: refused before any name was read.)"""
    names = [f"Zoe{i}" + BIDI + "n" * 10 for i in range(9_999)] + ["x" * 100_000]
    states = {"characters": [{"name": name, "position": [1.0, 1.0], "action": "idle"} for name in names]}
    spec = program_run(box.file("prog.py", CLEAN_PROGRAM), "program")
    spec.argv += ["--states", str(box.file("states.json", json.dumps(states)))]
    spec.check_output = refused_for("unknown character 'Zoe'", "Zoe0\\u202e\\u2066\\x1b[31m")
    return spec


@attack("program", "the program's worker writes 1 MB of escapes, bidi and bytes that are not UTF-8 to stderr")
def _program_worker_stderr(box: Box) -> Spec:
    """Stands in for a crash of the worker (a bug) whose traceback quotes hostile input: a
    ``sitecustomize`` on the ``PYTHONPATH`` writes in the worker only (which inherits no
    ``STORYTELLER_*`` variable), and the worker then runs the program as usual."""
    noise = (BIDI + "\x1b]0;title\x07").encode() + b"\xff\xfe File \"x.py\", line 1\n"
    (box.root / "site").mkdir()
    (box.root / "site" / "sitecustomize.py").write_text(
        "import os\n"
        "if 'STORYTELLER_SCRIPTED_STORY_KEY' not in os.environ:\n"
        f"    os.write(2, {noise!r} * {(1 << 20) // len(noise)})\n",
        encoding="utf-8",
    )
    checkout = str(Path(__file__).resolve().parents[2])
    path = os.pathsep.join(p for p in (str(box.root / "site"), checkout, os.environ.get("PYTHONPATH")) if p)
    spec = program_run(box.file("ok.py", CLEAN_PROGRAM), "program")
    spec.env = {"PYTHONPATH": path}
    spec.writable = (box.root / "site" / "__pycache__",)  # the worker compiles sitecustomize
    return spec


@attack("environment", "STORYTELLER_LOCAL_THREADS=\u00b2 (a digit int() refuses)")
def _env_threads(box: Box) -> Spec:
    return Spec(["model", "info"], "model info", "bad", env={"STORYTELLER_LOCAL_THREADS": "\u00b2"})


@attack("environment", "STORYTELLER_LOCAL_PREFIX_SLOTS=abc (run)")
def _env_slots(box: Box) -> Spec:
    out = box.root / "o"
    return Spec(["run", "home", "-d", "2", "--out", str(out), "--no-interactive", "--no-live"], "run", "bad",
                writable=(out,), env={"STORYTELLER_LOCAL_PREFIX_SLOTS": "abc"})


@attack("environment", "STORYTELLER_CONFIG a FIFO, STORYTELLER_MODEL with escapes and bidi")
def _env_config(box: Box) -> Spec:
    fifo = box.fifo(box.root / "cfg.toml")
    return Spec(["model", "info"], "model info", "bad", env={"STORYTELLER_CONFIG": str(fifo),
                                                            "STORYTELLER_MODEL": "openai/x" + BIDI})


@attack("environment", "STORYTELLER_CACHE_DIR a file, STORYTELLER_REFERENCE a FIFO (replay)")
def _env_cache(box: Box) -> Spec:
    box.copy_run()
    out = box.root / "replayed"
    return Spec(["replay", str(box.run), "--out", str(out), "--no-live"], "replay", "either", writable=(out,),
                env={"STORYTELLER_CACHE_DIR": str(box.file("cache", "not a folder")),
                     "STORYTELLER_REFERENCE": str(box.fifo(box.root / "ref"))})
