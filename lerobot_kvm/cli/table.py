"""Aligned text tables of per-scenario results, shared by the measuring commands."""


def results_table(rows: list[dict], columns: tuple[tuple[str, str, str], ...]) -> str:
    """One line per row; `columns` are (header, row key, format). The last column names the failed checks
    (each row carries `passes`: check -> bool | None and `passed`)."""
    header = [h for h, _, _ in columns] + ["result"]
    lines = []
    for row in rows:
        cells = ["-" if row[key] is None else fmt.format(row[key]) for _, key, fmt in columns]
        failed = [name for name, ok in row["passes"].items() if ok is False]
        cells.append("pass" if row["passed"] else "FAIL: " + ", ".join(failed))
        lines.append(cells)
    widths = [max(len(c) for c in col) for col in zip(header, *lines, strict=True)]
    numeric = [fmt != "{}" for _, _, fmt in columns] + [False]

    def fmt_line(cells: list[str]) -> str:
        padded = (c.rjust(w) if num else c.ljust(w) for c, w, num in zip(cells, widths, numeric, strict=True))
        return "  ".join(padded).rstrip()

    return "\n".join([fmt_line(header), fmt_line(["-" * w for w in widths]), *map(fmt_line, lines)])
