#!/usr/bin/env bash
# The product speaks of what the code does and what was measured, never of the internal work rounds that
# produced it ("stop 43", "issue 20", "round 3"): a user cannot know what they were. This check (run by .ci/run)
# fails, exit 1, listing
#   - every line of a tracked file under src conf scripts docs tests results notebooks README.md mkdocs.yml that
#     names a work round, as FILE:LINE:text (CHANGELOG.md, this script and its test are left out), and
#   - every tracked path that carries a round number (e.g. results/x_stop41.md, scripts/fb_issue20.sh).
# Say instead what the thing is and why (the measured reason, the results file that holds the numbers).
#   bash scripts/check_product_text.sh [CHECKOUT_DIR]     (default: this checkout)
set -uo pipefail
cd "${1:-$(dirname "$0")/..}" || exit 2
git rev-parse --is-inside-work-tree >/dev/null 2>&1 || { echo "check_product_text: $(pwd) is not a git checkout" >&2; exit 2; }

# a round word followed by its number: "stop 43", "Stops 34 - 43", "issue-20", "issue #20", "stop44", "issue20_x"
WORDS='(^|[^[:alnum:]])(stop|round|issue)s?[ _#-]{0,2}[0-9]{1,3}([^0-9]|$)'
# a path naming a round: "fb_speed_stop41.md", "fb_issue20.sh", "stop43/", "x_issue/"
PATHS='(stop|issue|round)s?[_-]?[0-9]|_(stop|issue)s?([^[:alpha:]]|$)'
SCOPE=(src conf scripts docs tests results notebooks README.md mkdocs.yml)
LEFT_OUT=(':!CHANGELOG.md' ':!scripts/check_product_text.sh' ':!tests/test_product_text.py')

lines=$(git grep -n -I -i -E -e "$WORDS" -- "${SCOPE[@]}" "${LEFT_OUT[@]}")
rc=$?
[ "$rc" -le 1 ] || { echo "check_product_text: git grep failed (exit $rc)" >&2; exit 2; }
paths=$(git ls-files | grep -i -E -e "$PATHS")

n_lines=0 n_paths=0
[ -n "$lines" ] && n_lines=$(printf '%s\n' "$lines" | wc -l)
[ -n "$paths" ] && n_paths=$(printf '%s\n' "$paths" | wc -l)
if [ "$n_lines" -gt 0 ]; then
  echo "lines naming an internal work round (say what it is and why, cite the results file instead):"
  printf '%s\n' "$lines"
fi
if [ "$n_paths" -gt 0 ]; then
  echo "paths carrying a round number (rename by content with git mv, then update every reference):"
  printf '%s\n' "$paths"
fi
echo "check_product_text: $n_lines line(s), $n_paths path(s)"
[ "$n_lines" -eq 0 ] && [ "$n_paths" -eq 0 ]
