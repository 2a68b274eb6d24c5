#!/usr/bin/env bash
# Regenerates the bundled recordings (seeded: byte-for-byte reproducible except MCAP library headers).
set -euo pipefail
cd "$(dirname "$0")"
rg() { "${ROLLERGEAR:-rollergear}" "$@"; }
start=2023-11-14T22:13:20Z  # the bundled recordings' date (simulate dates a recording now unless told)
rg simulate --out rig_map.mcap --profile rig_map --rate 200 --seed 1 --start $start
rg simulate --out rig_map_drag.mcap --profile bidirectional_map --rate 100 --seed 2 --start $start \
   --effect drag_speed:c=3e-4,p=1.4 --effect drag_constant:c=0.04
rg simulate --out drive_cycle_joint_states.mcap --profile drive_cycle --rate 100 --seed 3 --start $start --joint-states \
   --effect load_dependent:c=1.5e-3,q=1.0
rg simulate --out warmup.mcap --profile warmup --rate 100 --seed 4 --start $start --effect viscosity_temperature:B=700
