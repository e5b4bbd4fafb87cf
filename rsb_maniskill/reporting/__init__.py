"""Reports from eval records, a leaf over the records, the store and the metrics: the summary
files (``summary.py``: paper tables, JSON, CSV, PNG), the robustness, reasoning-following and
semantic-gap sections (``robustness.py``, ``reasoning.py``, ``gap.py``), ``results.json``
(``results.py``), ``rsb report``'s self-contained HTML page (``page.py`` and ``templates/``),
the writer that puts them in a results directory (``writer.py``), the cell formats they share
(``cells.py``) and vla-eval results read as records (``vla_eval_results.py``)."""
