"""The kinds of plugin components (re-exported as fusion.api.KINDS; here so the CLI parser needs no numpy)."""

KINDS = ("process", "measurement", "filter", "gate", "decoder", "solver", "source", "sink", "simulator",
         "importer")
