"""Closed-loop evaluation and the field's protocols on a corpus, their statistics and report."""
