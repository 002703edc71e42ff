"""End-to-end benchmarks of the application: they run `handeye calibrate`, read and write sessions,
import files and load configs, so they live in the app layer (`bench/` holds the library and device
benchmarks). Run them through ``handeye bench --faults | --fuzz | --model | --plan`` or
``python -m bench.<name>``."""
