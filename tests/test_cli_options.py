"""Option validation of the command line (issue 12, point 2): every option value is checked
before work starts, each bad one refused with one ``error:`` line naming the option, exit code 2,
and nothing written."""

import pytest

import spaceid._memory
from spaceid import SpaceidError
from spaceid.cli import main
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import resolve_anchors
from spaceid.models import load_model

SIM = ("simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", "0.4934")
DESIGN = ("design", "cepheus", "--duration", "5", "--harmonics", "3", "--momentum", "0.4934")
MC = ("montecarlo", "cepheus", "--momentum", "0.4934")

CASES = {
    "simulate negative seed": ([*SIM, "--rate", "50", "--seed", "-1"], "--seed: -1 is not an integer >= 0"),
    "experiment negative seed": (["experiment", "--seed", "-1"], "--seed: -1 is not an integer >= 0"),
    "design fractional seed": ([*DESIGN, "--samples", "30", "--seed", "1.5"], "--seed: 1.5 is not an integer"),
    "simulate rate 1e9": ([*SIM, "--rate", "1e9"], r"--rate 1e\+09: 5e\+09 samples would need about .* GiB of "
                          "memory, more than the .* GiB available: give fewer samples or a lower --rate"),
    "simulate samples 1e9": ([*SIM, "--samples", "1e9"], "--samples 1000000000 would need about .* GiB"),
    "simulate rate 1e200": ([*SIM, "--rate", "1e200"], r"--rate 1e\+200: 5e\+200 samples would need"),
    "simulate rate too low": ([*SIM, "--rate", "0.1"], "--rate 0.1: 1 sample over the trajectory's 5 s"),
    "simulate rate nan": ([*SIM, "--rate", "nan"], "--rate: nan is not a finite number > 0"),
    "simulate noise nan": ([*SIM, "--rate", "50", "--noise-angle", "nan"], "--noise-angle: nan is not a finite "
                           "number >= 0: give a standard deviation"),
    "simulate noise negative": ([*SIM, "--rate", "50", "--noise-rate", "-1e-3"], "--noise-rate: -1e-3 is not"),
    "identify noise inf": (["identify", "cepheus", "log.csv", "--momentum", "0.4934", "--noise-base-rate", "inf"],
                           "--noise-base-rate: inf is not a finite number >= 0"),
    "simulate planar momentum out of plane": ([*SIM[:-1], "1,2,0.4934", "--rate", "50"],
                                              "--momentum: '1,2,0.4934' has in-plane components hx, hy, but a "
                                              "planar model carries only the momentum about z: give --momentum "
                                              "0.4934"),
    "identify repeated anchor": (["identify", "cepheus", "log.csv", "--momentum", "0.4934", "--known", "pi5=1",
                                  "--known", "pi5=2"], "--known: pi5 is given twice .1 and 2.: give each anchor once"),
    "predict initial yaw nan": (["predict", "r.json", "paper-table2", "--momentum", "0.4934", "--initial-yaw", "nan"],
                                "--initial-yaw: nan is not a finite number"),
    "design samples 1e9": ([*DESIGN, "--samples", "1e9"], "--samples 1000000000 would need about"),
    "design harmonics bounded": ([*DESIGN, "--samples", "30", "--harmonics", "100000"],
                                 "--harmonics: 100000 is not an integer >= 1 and <= 50"),
    "design duration nan": (["design", "cepheus", "--duration", "nan", "--harmonics", "3", "--samples", "30",
                             "--momentum", "0.4934"], "--duration: nan is not a finite number > 0"),
    "montecarlo runs bounded": ([*MC, "--runs", "1e9"], "--runs: 1e9 is not an integer >= 2 and <= 100000"),
    "montecarlo samples 1e9": ([*MC, "--samples", "1000000000", "--runs", "2"], "--samples 1000000000 would need"),
    "montecarlo negative seed": ([*MC, "--seed", "-2"], "--seed: -2 is not an integer >= 0"),
    "experiment samples": (["experiment", "--samples", "1"], "--samples: 1 is not an integer >= 2"),
    "export region": (["export", "r.json", "--prior", "cepheus", "--region", "2"], "--region: 2 is not a finite "
                      "number > 0 and <= 0.999999: give a probability"),
}


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_bad_option_is_one_line_exit_2_before_any_work(case, tmp_path, capsys, monkeypatch):
    args, message = CASES[case]
    monkeypatch.chdir(tmp_path)
    assert main([*args, "-o", "out"] if args[0] in ("simulate", "identify", "design", "predict", "export")
                else [*args, "--out", "out"]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err, err
    assert pytest.importorskip("re").search(message, lines[0]), lines[0]
    assert not list(tmp_path.iterdir())  # nothing written, not even an empty folder


def test_predict_refuses_two_initial_attitudes(tmp_path, capsys):
    log = tmp_path / "log.csv"
    assert main([*SIM, "--samples", "20", "-o", str(log)]) == 0
    assert main(["identify", "cepheus", str(log), "--momentum", "0.4934", "-o", str(tmp_path / "r.json")]) == 0
    capsys.readouterr()
    code = main(["predict", str(tmp_path / "r.json"), "paper-table2", "--momentum", "0.4934", "--samples", "20",
                 "--initial-yaw", "0.1", "--initial-quat", "1,0,0,0", "-o", str(tmp_path / "p.csv")])
    assert code == 2 and not (tmp_path / "p.csv").exists()
    assert capsys.readouterr().err == ("error: --initial-yaw and --initial-quat both give the initial attitude: "
                                       "give one\n")


def test_memory_estimate_refuses_what_the_machine_cannot_hold(tmp_path, capsys, monkeypatch):
    """simulate --rate 20000 on Cepheus (1e5 samples, a 14 MB log) peaked at 2.2 GB: refused on a
    machine with 1 GiB available, with the numbers; run where it fits."""
    monkeypatch.setattr(spaceid._memory, "available_memory", lambda: 1.0 * spaceid._memory.GiB)
    assert main([*SIM, "--rate", "20000", "-o", str(tmp_path / "big.csv")]) == 2
    line = capsys.readouterr().err.strip()
    assert line.startswith("error: --rate 20000: 1e+05 samples would need about 2.96 GiB of memory, more than the "
                           "1 GiB available"), line
    assert not (tmp_path / "big.csv").exists()
    monkeypatch.setattr(spaceid._memory, "available_memory", lambda: 64.0 * spaceid._memory.GiB)
    assert main([*SIM, "--rate", "20", "-o", str(tmp_path / "small.csv")]) == 0


def test_two_names_of_one_anchor_are_refused():
    """``--known`` by its minimal name and by the physical parameter it equals alone: one parameter twice."""
    param = minimal_parameters(load_model("cepheus-rw"))
    name = next(n for n, d in zip(param.names, param.definitions) if d.strip() == "Iczz_wheel")
    with pytest.raises(SpaceidError, match=rf"`known` {name} and `known` Iczz_wheel both set {name} "
                                           r"\(= Iczz_wheel\): give it once"):
        resolve_anchors(param, {name: 0.002, "Iczz_wheel": 0.00197}, "log.csv")
    assert resolve_anchors(param, {"Iczz_wheel": 0.00197}, "log.csv")  # once is fine
