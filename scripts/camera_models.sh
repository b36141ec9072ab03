#!/usr/bin/env bash
# The camera-model study (issue 59 item 5; its plan: configs/sweep/cpu_camera_models.yaml; its page:
# scripts/publish_camera_models.py -> docs/results/camera_models.md). One sweep folder per arm under OUT; the arms of
# a rig share its rendered worlds and every arm the first arm's pretraining (hard links, made before an arm starts,
# as `mcdp calibrate` does), so arms differ by their switch only. Two chains, one per core: the distorted rig's six
# arms, and the fisheye rig's three. A rerun resumes every arm (each sweep skips what it has).
#
#   bash scripts/camera_models.sh sweeps/camera_models            # both chains, side by side
#   bash scripts/camera_models.sh sweeps/camera_models distorted  # one chain
#   python scripts/publish_camera_models.py --collect sweeps/camera_models
set -euo pipefail
OUT=${1:?usage: camera_models.sh OUT [distorted|fisheye]}
ONLY=${2:-}
PRESET=configs/sweep/cpu_camera_models.yaml
MCDP=${MCDP:-mcdp}
PYTHON=${PYTHON:-python}
# the preset's train_overrides and the as-if-pinhole switch (an override replaces the whole list)
PINHOLE="train_overrides=[$("$PYTHON" -c 'import sys, yaml; print(", ".join(yaml.safe_load(open(sys.argv[1]))["train_overrides"]))' "$PRESET"), model.lens=pinhole]"
FISHEYE=(data=configs/data/fisheye.yaml
         "data_overrides=[camera.width=96, camera.height=72, dataset.sequences=64, dataset.frames=10, scene.texture_size=128, render.shadow_map_size=1024]"
         "overlaps=[0.5263]" plan.overlap=0.5263 "seeds=[730,731,732,733,734,735]")

share() {  # share FIRST's pretraining (and, with a third argument, its worlds) with ARM's folder
  local first=$1 arm=$2 worlds=${3:-}
  [ -d "$OUT/$arm" ] && return 0
  mkdir -p "$OUT/$arm"
  [ -d "$OUT/$first/pretrain" ] && cp -al "$OUT/$first/pretrain" "$OUT/$arm/"
  [ -n "$worlds" ] && [ -d "$OUT/$first/data" ] && cp -al "$OUT/$first/data" "$OUT/$arm/"
  [ -e "$OUT/$first/.mcdp" ] && cp -l "$OUT/$first/.mcdp" "$OUT/$arm/"
  return 0
}

arm() {  # ARM METHOD [sweep overrides...]
  local name=$1 method=$2
  shift 2
  echo "camera_models: arm $name" >&2
  "$MCDP" sweep "$PRESET" --out "$OUT/$name" --no-progress "methods=[$method]" "$@"
}

distorted() {
  arm mono2_lens mono2
  for a in mono2_pinhole:mono2 mcdp_m2_lens:mcdp_m2 mcdp_m2_pinhole:mcdp_m2 fsm_lens:fsm fsm_pinhole:fsm; do
    name=${a%%:*}; method=${a##*:}
    share mono2_lens "$name" worlds
    if [[ $name == *_pinhole ]]; then
      arm "$name" "$method" "$PINHOLE"
    else
      arm "$name" "$method"
    fi
  done
}

fisheye() {
  share mono2_lens mono2_fisheye  # the pretraining only: the fisheye rig renders worlds of its own
  arm mono2_fisheye mono2 "${FISHEYE[@]}"
  for a in mcdp_m2_fisheye:mcdp_m2 fsm_fisheye:fsm; do
    name=${a%%:*}; method=${a##*:}
    share mono2_fisheye "$name" worlds
    arm "$name" "$method" "${FISHEYE[@]}"
  done
}

mkdir -p "$OUT"
case "$ONLY" in
  distorted) distorted ;;
  fisheye) fisheye ;;
  "") distorted & d=$!; fisheye & f=$!; rc=0; wait $d || rc=$?; wait $f || rc=$?; exit $rc ;;
  *) echo "camera_models.sh: the chain must be distorted or fisheye, got '$ONLY'" >&2; exit 2 ;;
esac
