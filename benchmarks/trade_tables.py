"""Measure every registered trade topic and write the "Speed and accuracy" docs page.

For each topic of ``tactile-rig trade`` installed here (or those named with ``--topics``) this runs
the topic's measurement (speed and accuracy of every setting in one run), and with ``--save``:

* writes its table to ``benchmarks/results/trade_<topic>.json`` (with the conditions it ran under),
* draws ``docs/img/trade_<topic>.png`` (error against speed, front and default marked),
* rewrites ``docs/speed_and_accuracy.md`` from every saved table (topics not measured this time keep
  their last saved section), each figure and table with the command that regenerates it.

Without ``--save`` it prints the page to stdout and writes nothing. ``--render-only`` rebuilds the
page and plots from the saved tables without measuring. ``--quick`` runs are never saved (their
tables hold fewer episodes/frames per setting); use them to try the page.

Exit status 1 when a default is off its front and the topic gives no reason (the page says so too),
or when a topic failed to measure.

Usage::

    python benchmarks/trade_tables.py --save                      # every topic, full runs
    python benchmarks/trade_tables.py --save --topics collision   # one section
    python benchmarks/trade_tables.py --render-only --save        # page + plots from saved tables
    python benchmarks/trade_tables.py --quick                     # try it: print the page only
"""

from __future__ import annotations

import argparse
import json
import sys
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _output import RESULTS_DIR, add_save_args, parse_args  # noqa: E402

from tactile_rig.rig import trade  # noqa: E402
from tactile_rig.rig.trade.conditions import conditions_text  # noqa: E402
from tactile_rig.rig.trade.table import TradeTable, setting_text  # noqa: E402

DOC = ROOT / "docs" / "speed_and_accuracy.md"
IMG = ROOT / "docs" / "img"
PAGE_CMD = "python benchmarks/trade_tables.py --save"


def result_file(topic: str) -> Path:
    return RESULTS_DIR / f"trade_{topic}.json"


def load_saved(topic: str) -> TradeTable | None:
    path = result_file(topic)
    if not path.is_file():
        return None
    return TradeTable.from_dict(json.loads(path.read_text(encoding="utf-8")))


def _best(t: TradeTable, key: str) -> str:
    front = t.front()
    if not front:
        return "-"
    i = front[0] if key == "speed" else front[-1]
    r = t.rows[i]
    return f"`{setting_text(r.setting)}` ({r.speed:.4g} {t.speed_name}, " \
           f"{r.error:.4g} {t.error_name})"


def section(topic: str, t: TradeTable | None, summary: str, *, img_rel: str | None) -> str:
    lines = [f"<!-- trade:{topic} -->", f"## {topic}", ""]
    if summary:
        lines += [summary[0].upper() + summary[1:] + ".", ""]
    if t is None:
        lines += [f"Not measured yet in this checkout: `tactile-rig trade {topic}` then `{PAGE_CMD} --topics "
                  f"{topic}` fill this section.", f"<!-- /trade:{topic} -->", ""]
        return "\n".join(lines)
    lines += [f"**Data**: {t.data}.", ""]
    lines += [f"**Speed**: `{t.speed_name}` (higher is better); **error**: `{t.error_name}` (lower is better)."]
    if t.knobs:
        lines += ["", "Knobs: " + "; ".join(f"`{k}`: {v}" for k, v in t.knobs.items()) + "."]
    lines.append("")
    if img_rel:
        lines += [f"![trade {topic}: {t.error_name} against {t.speed_name}]({img_rel})", "",
                  f"*Figure: `tactile-rig trade {topic} --plot docs/img` (a quick look: add `--quick`); "
                  f"this section: `{PAGE_CMD} --topics {topic}`.*", ""]
    lines += [t.to_markdown(), ""]
    if not t.default_on_front() and not t.default_note:
        lines += ["**The default is not on the front and the topic gives no reason: this is a finding to act on "
                  "(move the default, or say why it stays).**", ""]
    lines += [f"Table: `tactile-rig trade {topic}` (JSON: add `--json`; saved in "
              f"`benchmarks/results/trade_{topic}.json`).", f"<!-- /trade:{topic} -->", ""]
    return "\n".join(lines)


def page(tables: dict[str, TradeTable | None], summaries: dict[str, str], img_rel: dict[str, str | None]) -> str:
    head = [
        "# Speed and accuracy",
        "",
        "Every speed/accuracy knob of the rig, measured: for each setting the speed and the error come from "
        "the same run on the same data, so they can be compared row by row. A row is on the **Pareto front** "
        "when no other row is at least as fast and at least as accurate (one of the two strictly; speeds "
        "within the table's tolerance count as equal, since a shared machine's timings wobble). **D** marks "
        "the shipped default; where the default is not on the front the section says why.",
        "",
        f"Regenerate the whole page (full runs; plots in `docs/img/`, tables in `benchmarks/results/trade_*.json`): "
        f"`{PAGE_CMD}`. One topic: `{PAGE_CMD} --topics TOPIC`. Try a topic without writing anything: "
        "`tactile-rig trade TOPIC --quick` (fewer episodes or frames per setting, never fewer settings; "
        "`--json`, `--plot DIR`).",
        "",
        "Speeds are wall-clock figures on the machine named under each table (a shared 2-core machine unless "
        "it says otherwise: the load average before and after the run is recorded); errors do not depend on "
        "the machine.",
        "",
        "Adding a topic: one module in `tactile_rig/rig/trade/` with `TOPIC`, `SUMMARY` and "
        "`measure(*, quick, seed) -> TradeTable` (every setting measured in one run, the default marked, "
        "`default_note` saying why when it is off the front), plus its line in `TOPICS` "
        "(`tactile_rig/rig/trade/__init__.py`); `tactile_rig.rig.trade.timing.rates_per_s` times settings "
        "interleaved, so a load spike hits them all alike.",
        "",
        "| topic | default | default on the front? | fastest on the front | most accurate on the front |",
        "|---|---|---|---|---|",
    ]
    for topic, t in tables.items():
        if t is None:
            head.append(f"| [{topic}](#{topic}) | - | not measured yet | - | - |")
            continue
        defaults = "<br>".join(f"`{setting_text(t.rows[i].setting)}`"
                               for i in t.default_indices)
        on = "yes" if t.default_on_front() else ("no: " + (t.default_note or "**no reason given**"))
        if t.group_by:  # one front per group: the section lists them
            best = worst = f"one front per `{t.group_by}`: see the section"
        else:
            best, worst = _best(t, "speed"), _best(t, "error")
        head.append(f"| [{topic}](#{topic}) | {defaults} | {on.replace('|', '/')} | {best} | {worst} |")
    head.append("")
    body = [section(topic, t, summaries.get(topic, ""), img_rel=img_rel.get(topic)) for topic, t in tables.items()]
    return "\n".join(head) + "\n" + "\n".join(body)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer episodes/frames per setting; never saved")
    ap.add_argument("--topics", nargs="*", help="measure only these topics (default: every installed one)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--render-only", action="store_true",
                    help="measure nothing: rebuild the page and plots from benchmarks/results/trade_*.json")
    add_save_args(ap, "trade_<topic>.json")
    args = parse_args(ap)
    installed = trade.available_topics()
    registered = sorted(trade.TOPICS)
    todo = [] if args.render_only else (args.topics or installed)
    for t in todo:
        trade.topic_module(t)  # unknown or absent: one error before anything runs
    status = 0
    measured: dict[str, TradeTable] = {}
    for topic in todo:
        print(f"measuring {topic} ...", file=sys.stderr, flush=True)
        try:
            measured[topic] = trade.measure(topic, quick=args.quick, seed=args.seed)
        except Exception:  # noqa: BLE001 - one failing topic must not cost the others
            print(f"trade {topic} failed:\n{traceback.format_exc()}", file=sys.stderr)
            status = 1
            continue
        print(measured[topic].format_text(), file=sys.stderr)
        if args.save or args.out:
            path = Path(args.out) / f"trade_{topic}.json" if args.out else result_file(topic)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(measured[topic].to_dict(), indent=1) + "\n", encoding="utf-8")
            print(f"wrote {path}", file=sys.stderr)

    tables: dict[str, TradeTable | None] = {}
    summaries: dict[str, str] = {}
    for topic in registered:
        t = measured.get(topic)
        if t is None and (args.save or args.render_only):
            t = load_saved(topic)
        tables[topic] = t
        summaries[topic] = trade.summary(topic) if topic in installed else ""
    if not (args.save or args.render_only):
        tables = {k: v for k, v in tables.items() if v is not None}
    img_rel: dict[str, str | None] = {}
    for topic, t in tables.items():
        img_rel[topic] = None
        if t is not None and (args.save or args.out):
            img_dir = Path(args.out) / "img" if args.out else IMG
            t.plot(img_dir / f"trade_{topic}.png")
            img_rel[topic] = f"img/trade_{topic}.png"
        if t is not None and not t.default_on_front() and not t.default_note:
            print(f"trade {topic}: the default is off the front and no reason is given", file=sys.stderr)
            status = 1
    text = page(tables, summaries, img_rel)
    if args.save:
        DOC.write_text(text, encoding="utf-8")
        print(f"wrote {DOC}", file=sys.stderr)
    elif args.out:
        (Path(args.out) / "speed_and_accuracy.md").write_text(text, encoding="utf-8")
        print(f"wrote {Path(args.out) / 'speed_and_accuracy.md'}", file=sys.stderr)
    else:
        print(text)
        if args.render_only:
            print("(render only, not saved: add --save to write the page and plots)", file=sys.stderr)
    for topic, t in measured.items():
        print(f"{topic}: {conditions_text(t.conditions)}", file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
