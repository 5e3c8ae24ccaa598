# shellcheck shell=bash
# The rollout-option words of the bed's scripts (fb_ablation.sh variants "full+noise3+corr1+alt+sel",
# fb_recipe_eval.sh OPTIONS) and what each becomes, in one table: an evaluate override, a flag of the tools that
# choose and map a net (fb-select, fb_stability), or a flag of fb_speed (which times the net's steps and takes no
# mixing option). Sourced, so every script spells an option the same way.
#   rollout_options "full+alt+noise1" [overrides|flags|speed]
rollout_options() {
  local rest=${1#*+} mode=${2:-overrides} opt out="" override flag speed
  case "$1" in *+*) ;; *) rest="" ;; esac
  for opt in ${rest//+/ }; do
    case "$opt" in
      alt) override="fluidized_bed.mirror_alternate=true" flag="--mirror-alternate" speed=$flag ;;
      noise[0-9]*) override="fluidized_bed.rollout_noise=${opt#noise}" flag="--rollout-noise ${opt#noise}" speed=$flag ;;
      corr[0-9]*) override="fluidized_bed.advection_correction=${opt#corr}" flag="--advection-correction ${opt#corr}" speed="" ;;
      sel) override="" flag="" speed="" ;;
      *) echo "unknown rollout option '$opt' in '$1' (known: alt, noiseX e.g. noise1, corrX e.g. corr1, sel)" >&2; return 2 ;;
    esac
    case "$mode" in
      overrides) out="$out $override" ;;
      flags) out="$out $flag" ;;
      speed) out="$out $speed" ;;
      *) echo "rollout_options: unknown mode '$mode' (overrides, flags or speed)" >&2; return 2 ;;
    esac
  done
  echo "$out"
}
