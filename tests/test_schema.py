"""The typed schema: one declaration per key, read by everything; the README's key table is
generated from it (``python tests/test_schema.py --write`` rewrites it)."""

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from raimcore import algorithms
from raimcore.scenario import Scenario, from_dict, load_scenario, scenario_keys
from raimcore.schema import Key, SchemaError, coerce_float, coerce_int, option

README = Path(__file__).resolve().parents[1] / "README.md"
BEGIN, END = "<!-- keys:begin -->", "<!-- keys:end -->"


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|")


def _default(k: Key) -> str:
    v = k.default
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"' if v else '""'
    if isinstance(v, tuple):
        return "[" + ", ".join(f'"{x}"' if isinstance(x, str) else str(x) for x in v) + "]"
    return f"{v:g}" if isinstance(v, float) else str(v)


def key_table() -> str:
    """The README's key table, from the schema."""
    lines = ["| key | default | unit | allowed | what |", "|---|---|---|---|---|"]
    for k in scenario_keys().values():
        lines.append(f"| `{k.name}` | `{_default(k)}` | {k.unit} | {_cell(k.allowed)} | "
                     f"{_cell(k.help)} |")
    lines += ["", "Options of each algorithm (scenario keys too; only the chosen algorithm's "
              "are accepted):", "", "| algorithm | option | default | unit | allowed | what |",
              "|---|---|---|---|---|---|"]
    owners: dict[str, list[str]] = {}
    first: dict[str, Key] = {}
    for name in algorithms.names():
        for k in algorithms.get(name).options:
            owners.setdefault(k.name, []).append(name)
            first.setdefault(k.name, k)
    for key_name, k in first.items():  # an option shared by several algorithms: one row
        who = ", ".join(f"`{n}`" for n in owners[key_name])
        lines.append(f"| {who} | `{k.name}` | `{_default(k)}` | {k.unit} | "
                     f"{_cell(k.allowed)} | {_cell(k.help)} |")
    return "\n".join(lines)


def _readme_block(text: str) -> str:
    return text.split(BEGIN, 1)[1].split(END, 1)[0].strip("\n")


def test_readme_key_table_is_the_schema():
    assert _readme_block(README.read_text()) == key_table(), (
        "README key table is out of date: run `python tests/test_schema.py --write`")


def test_every_scenario_field_declares_its_key_and_default():
    import dataclasses

    keys = scenario_keys()
    for f in dataclasses.fields(Scenario):
        if f.name in ("options", "notes"):
            continue
        assert f.name in keys, f"Scenario.{f.name} has no schema key"
        k = keys[f.name]
        assert k.default == f.default and k.help
        assert k.coerce(k.default) == k.default  # a default its own key accepts


def test_option_declarations_are_self_consistent():
    for name in algorithms.names():
        spec = algorithms.get(name)
        assert spec.resolve_options({}) == spec.defaults
        for k in spec.options:
            assert k.help and k.coerce(k.default) == k.default


@pytest.mark.parametrize("value", [np.float32(0.5), np.float64(2.0), np.int64(3), 3])
def test_numpy_scalars_are_numbers(value):
    assert coerce_float("x", value) == float(value)


@pytest.mark.parametrize("value", [True, "1", None, [1.0], math.nan, math.inf])
def test_booleans_strings_and_non_finite_are_not_numbers(value):
    with pytest.raises(SchemaError, match="^x must be"):
        coerce_float("x", value)


def test_integers_are_whole():
    assert coerce_int("n", 3.0) == 3 and coerce_int("n", np.int32(4)) == 4
    for bad in (3.5, True, "3", math.inf):
        with pytest.raises(SchemaError, match="n must be an integer"):
            coerce_int("n", bad)


def test_range_messages_name_the_interval_and_unit():
    k = scenario_keys()["sigma_m"]
    with pytest.raises(SchemaError, match=r"sigma_m must be in \[0.001, 10000\] m, got 0"):
        k.coerce(0)


def test_option_of_another_algorithm_is_refused_with_its_owner():
    with pytest.raises(SchemaError, match="gf_groups.*does not belong.*parity.*option of gf"):
        load_scenario("default", algorithm="parity", gf_groups=10)
    with pytest.raises(SchemaError, match="did you mean 'max_exclusions'"):
        Scenario(options={"max_exclusion": 2})


def test_unknown_key_did_you_mean():
    with pytest.raises(SchemaError, match="unknown scenario key 'sigma'.*did you mean"):
        from_dict({"sigma": 3})


def test_changing_algorithm_drops_the_old_options_and_says_so():
    s = load_scenario("seed001-flight", algorithm="parity")
    assert s.algorithm == "parity" and s.options == ()
    assert any("mss_ident_rule" in n and "left out" in n for n in s.notes)
    s2 = load_scenario("seed001-flight").replace(algorithm="gf")
    assert s2.options == ()


def test_option_declared_badly_is_a_declaration_error():
    with pytest.raises(ValueError, match="x must be an integer"):
        option("x", int, 1.5, "help")


def test_registry_survives_a_failing_algorithm_module():
    code = (
        "import raimcore.algorithms as a;"
        "a._MODULES.insert(1, 'no_such_algorithm_module');"
        "print(a.names()); print(a.failed())"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    names, failed = out.splitlines()
    assert "'parity'" in names and "'ekf'" in names and "'mss'" in names
    assert "no_such_algorithm_module" in failed and "ModuleNotFoundError" in failed


def test_raim_list_names_a_failing_module(tmp_path):
    code = (
        "import raimcore.algorithms as a, sys;"
        "a._MODULES.append('no_such_algorithm_module');"
        "from raimcore.cli import main; sys.exit(main(['list']))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0
    assert "no_such_algorithm_module failed to load" in out.stdout
    assert "parity" in out.stdout


if __name__ == "__main__":
    if "--write" in sys.argv:
        text = README.read_text()
        head, rest = text.split(BEGIN, 1)
        _, tail = rest.split(END, 1)
        README.write_text(f"{head}{BEGIN}\n{key_table()}\n{END}{tail}")
        print(f"wrote the key table into {README}")
    else:
        print(key_table())
