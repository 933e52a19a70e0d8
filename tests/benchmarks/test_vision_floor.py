"""benchmarks/vision_floor.py: its OpenCV clock counts what it claims, and the docs quote
the committed result (`python benchmarks/vision_floor.py` rewrites it)."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _floor_module():
    spec = importlib.util.spec_from_file_location("vision_floor", ROOT / "benchmarks/vision_floor.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_clock_counts_opencv_calls_only_while_entered_and_puts_cv2_back():
    floor = _floor_module()
    original = cv2.morphologyEx
    img = np.zeros((480, 640), np.uint8)
    img[100:200, 100:300] = 255
    kernel = np.ones((5, 5), np.uint8)
    clock = floor.OpenCvClock()
    with clock:
        assert cv2.morphologyEx is not original
        for _ in range(20):
            cv2.morphologyEx(img, cv2.MORPH_OPEN, kernel)
        np.sort(np.arange(200_000)[::-1])          # numpy work: not OpenCV's
    assert cv2.morphologyEx is original
    assert clock.calls == 20 and clock.ns > 0
    cv2.morphologyEx(img, cv2.MORPH_OPEN, kernel)   # outside: not counted
    assert clock.calls == 20


def test_the_docs_quote_the_committed_floor():
    result = json.loads((ROOT / "benchmarks/results/vision_floor.json").read_text())
    rows = re.findall(r"^\| (\w+) \| ([\d.]+) µs \(([\d.]+) calls\) \| ([\d.]+) µs \| ([\d.]+) µs "
                      r"\| ([\d.]+) \| ([\d.]+) \| ([\d.]+) % \|$",
                      (ROOT / "docs/performance.md").read_text(), flags=re.M)
    assert {r[0] for r in rows} == set(result["scenarios"]) == {"lenses", "squares"}
    for name, cv_us, calls, ours_us, blob_us, cv_ratio, ratio, glue in rows:
        got = result["scenarios"][name]
        med = got["median"]
        assert float(cv_us) == med["ours_opencv_us"] and float(calls) == med["opencv_calls"]
        assert float(ours_us) == med["ours_us"] and float(blob_us) == med["blob_us"]
        assert float(cv_ratio) == got["ours_opencv_over_blob"]
        assert float(ratio) == got["ours_over_blob"]
        assert float(glue) == round(100 * got["glue_share_of_ours"], 1)


def test_the_docs_quote_the_committed_bench():
    # docs/performance.md's third-round bench table against benchmarks/results/vision.json
    # (`python benchmarks/vision_bench.py --repeats 5` rewrites it)
    result = json.loads((ROOT / "benchmarks/results/vision.json").read_text())["scenarios"]
    text = (ROOT / "docs/performance.md").read_text()
    keys = {"with scikit-image's frames between": ("timing", "p50_ms"),
            "ours and the detector alone": ("timing_ours_and_blob_alone", "p50_ms"),
            "first call after a scikit-image frame": ("first_and_second_call",
                                                      "first_p50_ms"),
            "second call, the same frame": ("first_and_second_call", "second_p50_ms")}
    rows = re.findall(r"^\| ([^|]+?) \| ([\d.]+) / ([\d.]+) \| ([\d.]+) \| ([\d.]+) / ([\d.]+) "
                      r"\| ([\d.]+) \|$", text, flags=re.M)
    rows = [r for r in rows if r[0] in keys]
    assert [r[0] for r in rows] == list(keys)
    for label, *figures in rows:
        for name, (ours, blob, ratio) in zip(("lenses", "squares"),
                                             (figures[:3], figures[3:]), strict=True):
            table, column = keys[label]
            t = result[name][table]
            o, b = t["ours"][column], t["blob"][column]
            assert (float(ours), float(blob), float(ratio)) == \
                (round(o, 2), round(b, 2), round(o / b, 2)), (label, name)
    # the sentence on what cold caches cost each, squares
    twice = result["squares"]["first_and_second_call"]
    m = re.search(r"costs ours ([\d.]+) ms more than the second call on the same frame, and "
                  r"the detector ([\d.]+) ms more; warm, ours takes ([\d.]+) of the detector",
                  " ".join(text.split()))
    assert m, "the sentence is gone"
    ours_cold, blob_cold = (round(twice[p]["first_p50_ms"] - twice[p]["second_p50_ms"], 2)
                            for p in ("ours", "blob"))
    assert tuple(map(float, m.groups())) == (
        ours_cold, blob_cold,
        round(twice["ours"]["second_p50_ms"] / twice["blob"]["second_p50_ms"], 2))


def test_the_docs_quote_the_committed_simulator_speed_side_by_side():
    # docs/performance.md's "Simulator speed" paragraph on the kernels against its JSON
    result = json.loads((ROOT / "benchmarks/results/simspeed_vision_kernels.json").read_text())
    text = (ROOT / "docs/performance.md").read_text()
    m = re.search(r"before\s+([\d×, ]+?)\s+real time \(median of two runs each\), after\s+"
                  r"([\d×, ]+?);", text)
    assert m, "the paragraph is gone"
    quoted = {code: [int(v) for v in re.findall(r"\d+", group)]
              for code, group in (("before", m.group(1)), ("after", m.group(2)))}
    runs = result["runs"]
    assert quoted["before"] == [round(r["sim_per_wall"]) for r in runs if r["code"] != "after"]
    assert quoted["after"] == [round(r["sim_per_wall"]) for r in runs if r["code"] == "after"]
    assert len({(r["parts_per_minute"], r["located"], r["lost"]) for r in runs}) == 1


@pytest.mark.parametrize("name,what", [
    ("vision_lazy_contours.json", "this took"), ("vision_xycut.json", "the XY-cut took"),
    ("vision_otsu_kernel.json", "the compiled Otsu level took"),
    ("vision_bit_morph.json", "the bit-wise morphology took"),
    ("vision_golden_morph.json", "the golden-image call took")])
def test_the_docs_quote_the_vision_side_by_sides(name, what):
    # docs/performance.md's sentences on a change to the locator, against its side-by-side
    # JSON (benchmarks/side_by_side.py over vision_bench.py, squares)
    import statistics
    result = json.loads((ROOT / "benchmarks/results" / name).read_text())

    def mean_ratio(code: str, key: str) -> float:
        tables = [r["report"]["scenarios"]["squares"][key] for r in result["runs"]
                  if r["code"] == code]
        return round(statistics.mean(t["ours"]["p50_ms"] / t["blob"]["p50_ms"]
                                     for t in tables), 3)

    text = " ".join((ROOT / "docs/performance.md").read_text().split())
    m = re.search(rf"over (\w+) alternating pairs of bench runs {what} squares' three-way "
                  r"ratio from ([\d.]+) to ([\d.]+) on average, and alone from ([\d.]+) to "
                  r"([\d.]+)", text)
    assert m, "the sentence is gone"
    words = {"three": 3, "four": 4, "five": 5, "six": 6}
    assert words[m.group(1)] == result["passes"]
    assert tuple(map(float, m.groups()[1:])) == (
        mean_ratio("before", "timing"), mean_ratio("after", "timing"),
        mean_ratio("before", "timing_ours_and_blob_alone"),
        mean_ratio("after", "timing_ours_and_blob_alone"))
    answers = {json.dumps(r["report"]["scenarios"][sc]["answers"], sort_keys=True)
               for r in result["runs"] for sc in ("squares",)}
    assert len(answers) == 1                       # the same answers, before and after
