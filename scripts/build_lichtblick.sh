#!/usr/bin/env bash
# Builds Lichtblick's web app (the open-source continuation of Foxglove Studio 1.x, MPL-2.0) outside
# this repository, for scripts/viewer_screenshot.py. Nothing of it is committed here.
#
#   scripts/build_lichtblick.sh GIT_DIR DEST     # e.g. GIT_DIR=lichtblick/.git from
#                                                # git clone https://github.com/lichtblick-suite/lichtblick
#   -> DEST/lichtblick/web/.webpack (about 42 MB; 2-core AMD EPYC under load ~8: install 2 min, webpack 9 min)
#
# Version: v1.28.1, commit 66adecb99ca4363b1028c750919c9046609f5c85. Needs node >= 20, npm, the npm
# registry. What differs from upstream's `yarn install --immutable && yarn web:build:prod`, and why:
#  - yarn 4.17.0 comes from npm (@yarnpkg/cli-dist) as .yarnrc.yml's yarnPath, not from corepack
#    (which downloads it from repo.yarnpkg.com, unreachable from the build machine);
#  - the npm registry the build machine reaches lacks five pinned packages, so package.json's
#    resolutions pin versions it has: @lichtblick/tsconfig 1.0.0 (for 1.1.2), @lichtblick/rosbag2 and
#    @lichtblick/rosbag2-web 1.0.0 (for 1.0.7 / 1.0.5; ROS 2 bag files only), flatbuffers_reflection
#    0.0.7 (for 1.3.0; flatbuffer schemas only); the lint-only @lichtblick/eslint-plugin is dropped;
#  - tsconfig 1.0.0 still says moduleResolution "node", which TypeScript 6 rejects as deprecated:
#    its base.json gets "ignoreDeprecations": "6.0";
#  - the type-check plugin and the source maps are switched off (LOGGRASP_SKIP_TSCHECK,
#    LOGGRASP_NO_SOURCEMAP): they only cost time, the bundle's code is the same;
#  - the two demo .bag fixtures and an icon source file (test assets, not in the web app) are left
#    out of the tree, as a git snapshot may not hold their blobs.
set -euo pipefail
COMMIT=66adecb99ca4363b1028c750919c9046609f5c85
YARN=4.17.0
src=$(cd "$1" && pwd)
dest=$(mkdir -p "$2" && cd "$2" && pwd)
[ -e "$dest/lichtblick" ] && { echo "error: $dest/lichtblick exists; give a new DEST" >&2; exit 2; }
cd "$dest"

tmp=$(mktemp -d)
git init -q --bare "$tmp/git"
echo "$src/objects" > "$tmp/git/objects/info/alternates"
export GIT_DIR="$tmp/git" GIT_INDEX_FILE="$tmp/git/index"
git read-tree "$COMMIT"
git rm -q --cached --ignore-unmatch e2e/fixtures/assets/demo-shuffled.bag \
  packages/suite-base/src/test/fixtures/demo-shuffled.bag packages/suite-desktop/resources/icon/BagIcon.afdesign
mkdir lichtblick.tmp
git archive "$(git write-tree)" | tar -x -C lichtblick.tmp
unset GIT_DIR GIT_INDEX_FILE
rm -rf "$tmp"
echo "$COMMIT" > lichtblick.tmp/.source-commit

npm pack -q "@yarnpkg/cli-dist@$YARN" >/dev/null
mkdir -p "yarn-$YARN" && tar -xzf "yarnpkg-cli-dist-$YARN.tgz" -C "yarn-$YARN" && rm "yarnpkg-cli-dist-$YARN.tgz"
yarn_js="$dest/yarn-$YARN/package/bin/yarn.js"

cd lichtblick.tmp
sed -i "s#^yarnPath:.*#yarnPath: $yarn_js#" .yarnrc.yml
node -e '
const fs = require("fs"); const p = JSON.parse(fs.readFileSync("package.json"));
delete p.devDependencies["@lichtblick/eslint-plugin"];
Object.assign(p.resolutions, {"@lichtblick/tsconfig": "1.0.0", "@lichtblick/rosbag2-web": "1.0.0",
  "@lichtblick/rosbag2": "1.0.0", "flatbuffers_reflection": "0.0.7"});
fs.writeFileSync("package.json", JSON.stringify(p, null, 2) + "\n");'
sed -i 's/^      new ForkTsCheckerWebpackPlugin({/      process.env.LOGGRASP_SKIP_TSCHECK ? false : new ForkTsCheckerWebpackPlugin({/' \
  packages/suite-base/webpack.ts
sed -i 's/prodSourceMap: "source-map",/prodSourceMap: process.env.LOGGRASP_NO_SOURCEMAP ? false : "source-map",/' \
  web/webpack.config.ts
grep -q LOGGRASP_SKIP_TSCHECK packages/suite-base/webpack.ts && grep -q LOGGRASP_NO_SOURCEMAP web/webpack.config.ts

export ELECTRON_SKIP_BINARY_DOWNLOAD=1 PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 PUPPETEER_SKIP_DOWNLOAD=1 HUSKY=0
export NODE_OPTIONS=--max-old-space-size=6144
nice -n 10 node "$yarn_js" install
sed -i 's#"moduleResolution": "node",#"moduleResolution": "node",\n    "ignoreDeprecations": "6.0",#' \
  node_modules/@lichtblick/tsconfig/base.json
grep -q ignoreDeprecations node_modules/@lichtblick/tsconfig/base.json
LOGGRASP_SKIP_TSCHECK=1 LOGGRASP_NO_SOURCEMAP=1 nice -n 10 node_modules/.bin/webpack --mode production \
  --config web/webpack.config.ts
grep -q LICHTBLICK_SUITE_DEFAULT_LAYOUT_PLACEHOLDER web/.webpack/index.html
cd .. && mv lichtblick.tmp lichtblick
echo "built: $dest/lichtblick/web/.webpack (Lichtblick $(node -p 'require("./lichtblick/package.json").version'), $COMMIT)"
