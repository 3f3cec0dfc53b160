"""The studies over the engine and the launchers: campaigns, the comparison, tuning, the
scorecard and its statistics, and the one-off studies behind the docs' tables."""
