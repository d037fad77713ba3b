"""Before / after on the same corpus: the summary rows of two sets of corpus runs side by side
(``signmap bench corpus-compare``). Each side may pool several JSONL files, e.g. two corpora of
consecutive seeds rendered apart, so a change is judged on every journey that both sides ran."""

from __future__ import annotations

from bench.corpus import report as corpus_report


def _rows(records: list[dict]) -> dict[str, list[str]]:
    """Summary table rows of ``records``: label -> [tuning cell, check cell]."""
    report = corpus_report.build_report({}, records)
    return {label: cells for label, *cells in corpus_report.summary_rows(report)}


def _other_inputs(before: list[dict], after: list[dict], names: list[str]) -> list[str]:
    """A warning naming the journeys whose bundles differ between the sides (renders of one seed
    on another machine), where both records carry ``bundle_digest``."""
    digests = [{r["name"]: r.get("bundle_digest") for r in side} for side in (before, after)]
    differ = [n for n in names
              if digests[0][n] and digests[1][n] and digests[0][n] != digests[1][n]]
    if not differ:
        return []
    return ["", f"**Not the same input:** rendered differently on the two sides: "
            f"{', '.join(differ)}; their differences are not the change's alone."]


def compare(before: list[dict], after: list[dict]) -> str:
    """A markdown table: every summary row, before and after, tuning and check half."""
    names = sorted({r["name"] for r in before} & {r["name"] for r in after})
    b, a = _rows([r for r in before if r["name"] in names]), _rows(
        [r for r in after if r["name"] in names])
    lines = [f"{len(names)} journeys run on both sides.", *_other_inputs(before, after, names), "",
             "|  | before, tuning | after, tuning | before, check | after, check |",
             "| --- | --- | --- | --- | --- |"]
    for label in [*b, *(k for k in a if k not in b)]:
        (bt, bc), (at, ac) = b.get(label, ["–", "–"]), a.get(label, ["–", "–"])
        lines.append(f"| {label} | {bt} | {at} | {bc} | {ac} |")
    return "\n".join(lines)
