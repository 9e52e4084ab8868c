"""pipeline/steps/: the steps.

Each step's work over typed values (calibration and view lines, tracking, segmentation, fixations
and targets, a target's estimate and status, the error model's bias, the exports, areas of interest,
a person's bias, imported and live recordings), with the file-level wrapper its step-by-step command
calls (read, call the step, write).

docs/architecture.md, "The rooms of pipeline/"."""
