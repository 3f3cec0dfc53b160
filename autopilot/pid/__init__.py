"""The cascaded PID baseline (issue 16): a second controller behind the TLC's contract."""
