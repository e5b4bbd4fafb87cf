"""Reports from eval records, a leaf over the records, the store and the metrics: the paper's
summary files (``summary.py``: tables, JSON, CSV, PNG), the report sections, one module each in
``sections/`` (robustness, reasoning following, the semantic gap, per-category, bias, confusion and
counterfactual tables: rows, JSON, Markdown, files and page; the registry ``sections.SECTIONS``),
``results.json`` and ``rsb report --compare`` (``results.py``; the paired tests in ``paired.py``),
``rsb report``'s self-contained HTML page (``page.py`` and ``templates/``), the writer that puts them in a
results directory
(``writer.py``), the cell formats they share (``cells.py``), the headings, notes and tables that
summary.md and the page are both rendered from (``blocks.py``), the plots' helpers (``figures.py``),
the leaderboard (``leaderboard.py``, ``leaderboard_files.py``, ``vla_eval_leaderboard.py``) and
vla-eval results read as records (``vla_eval_results.py``)."""
