"""Learned baselines trained on RSB demonstrations (optional extra ``baselines``)."""
