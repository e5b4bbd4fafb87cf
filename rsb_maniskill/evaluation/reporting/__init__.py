"""Reports from eval records: the summary files (``summary.py``: JSON, CSV, Markdown, PNG), the
robustness table (``robustness.py``) and ``rsb report``'s self-contained HTML page (``html_report.py``)."""
