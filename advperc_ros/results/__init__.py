"""What an attack leaves behind, in one place: where it goes, what it comes to, and the folder written.

- `destination`: an output folder checked writable (and with room) before any long work starts, and
  `exclusive`, the one lock an attack and a campaign hold on their output;
- `outcome`: what an attack comes to (the search's result and log, the best attack recorded);
- `report`: report.json's fields and report.md's text, built from the outcome;
- `plots`: the pictures (imported lazily by its callers: matplotlib is slow to import);
- `folder`: the results folder written from the outcome (bag, report, search log, plots), and read back.

This package sits in the application layer: the application, replay and campaigns write and read
results; nothing below them (core, ros, nodes, backends, params) imports it.
"""
