#!/usr/bin/env bash
# Fetches and prepares the licence-clean photographs the models are trained and tested on, then
# renders the training shards and the held-out test clips (models/README.md, docs/eval.md).
#
#   bash scripts/training-data.sh [DATA=../data]      # everything; each step skips what exists
#   STEP=photos bash scripts/training-data.sh          # only fetch and crop (photos, objects, manifest)
#   STEP=test   bash scripts/training-data.sh          # only the test clips
#   STEP=test-more bash scripts/training-data.sh       # 72 more clips each of shake and hand
#
# Sources, all from Debian's package archive (apt-get download; nothing is installed):
#   training scenes: mate-backgrounds (nature photos, GPL-2+), plasma-workspace-wallpapers
#     (GPL-2+), lomiri-wallpapers and lomiri-wallpapers-16.04 (CC-BY-SA / CC-BY, per file),
#     extremetuxracer-data (terrain photo textures, GPL-2+), python3-skimage (scikit-image's
#     sample photos; public domain / CC0, skimage/data/README.txt), gcompris-qt-data (Wikimedia
#     Commons photos of animals, monuments and musicians packed in Qt resource files; public
#     domain / CC0 / CC-BY / CC-BY-SA, per file in each activity's README, which names the source
#     page), tuxpaint-data (photo templates, GPL-2+), palapeli-data (puzzle photos, GPL-2+),
#     lxqt-themes (photo wallpapers only, CC-BY-SA-3.0 per wallpapers/License)
#   training objects (cut-outs with alpha): tuxpaint-stamps-default (GPL-2; photographic stamps
#     only: no `cartoon/`, `symbols/` or `space/`)
#   TEST ONLY (no file of these packages is used in training): ukui-wallpapers (CC-BY-SA-3.0),
#     lomiri-wallpapers-20.04 (CC-BY-SA-4.0 / CC-BY-4.0), python3-sklearn's sample photos
#     china.jpg and flower.jpg (CC-BY-2.0)
# None of the classic benchmark sets (Kodak, BSDS, McMaster, Set5/14, Urban100, DIV2K).
# $DATA/photos/MANIFEST.tsv lists every prepared file: its source package and version, licence,
# original path and use (train, test, object).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${1:-${DATA:-../data}}
STEP=${STEP:-all}
PIPELINE=${PIPELINE:-target/release/pipeline}
mkdir -p "$DATA/debs" "$DATA/src" "$DATA/photos/train" "$DATA/photos/test" "$DATA/objects"
DATA=$(cd "$DATA" && pwd)

TRAIN_PKGS=(mate-backgrounds plasma-workspace-wallpapers lomiri-wallpapers lomiri-wallpapers-16.04 extremetuxracer-data python3-skimage
            gcompris-qt-data tuxpaint-data palapeli-data lxqt-themes tuxpaint-stamps-default)
TEST_PKGS=(ukui-wallpapers lomiri-wallpapers-20.04 python3-sklearn)

photos() {
  (cd "$DATA/debs" && for p in "${TRAIN_PKGS[@]}" "${TEST_PKGS[@]}"; do
    ls "${p}"_*.deb >/dev/null 2>&1 || apt-get download "$p" 2>/dev/null
  done)
  for deb in "$DATA"/debs/*.deb; do
    p=$(basename "$deb"); p=${p%%_*}
    [ -d "$DATA/src/$p" ] || dpkg-deb -x "$deb" "$DATA/src/$p"
  done
  python3 - "$DATA" <<'PY'
import fnmatch, glob, os, re, struct, subprocess, sys, zlib
data = sys.argv[1]
src = f"{data}/src"

def rcc_files(path):
    """(name, bytes) of each file in a Qt binary resource (.rcc): 'qres', version, offsets of the
    tree, data and names; tree entries of 14 (v1) or 22 bytes; flag 2 a folder, 1 zlib, 4 zstd."""
    b = open(path, "rb").read()
    if b[:4] != b"qres":
        raise SystemExit(f"{path}: not a Qt resource file")
    ver, tree, dat, names = struct.unpack(">IIII", b[4:20])
    esz = 14 if ver == 1 else 22
    def name(off):
        n = struct.unpack(">H", b[names + off:names + off + 2])[0]
        return b[names + off + 6:names + off + 6 + 2 * n].decode("utf-16-be")
    def walk(i, prefix):
        e = tree + i * esz
        noff, flags = struct.unpack(">IH", b[e:e + 6])
        nm = name(noff) if i else ""
        if flags & 2:
            count, first = struct.unpack(">II", b[e + 6:e + 14])
            for c in range(first, first + count):
                yield from walk(c, f"{prefix}{nm}/" if i else "")
        else:
            off = dat + struct.unpack(">I", b[e + 10:e + 14])[0]
            raw = b[off + 4:off + 4 + struct.unpack(">I", b[off:off + 4])[0]]
            if flags & 1:
                raw = zlib.decompress(raw[4:])
            if not flags & 4:  # zstd entries are left out: none of the photographs is one
                yield prefix + nm, raw
    yield from walk(0, "")

def readme_licences(text):
    """GCompris's per-folder README: stanzas of Copyright/License/Source/Files; the licence of
    each listed file whose stanza names a Source (the photographs)."""
    out = {}
    for stanza in re.split(r"\n\s*\n", text):
        lic = re.search(r"^License:\s*(.+)$", stanza, re.M)
        srcl = re.search(r"^Source:\s*(\S+)", stanza, re.M)
        files = re.search(r"^Files:\s*(.*)", stanza, re.M | re.S)
        if lic and srcl and files:
            for f in files.group(1).split():
                out[f] = f"{lic.group(1).strip()} ({srcl.group(1)})"
    return out

def version(pkg):
    deb = glob.glob(f"{data}/debs/{pkg}_*.deb")[0]
    return os.path.basename(deb).split("_")[1].replace("%3a", ":")

def licence(pkg, path):
    """The DEP-5 stanza of the package's copyright file whose Files: glob matches the path."""
    text = open(glob.glob(f"{src}/{pkg}/usr/share/doc/*/copyright")[0], errors="replace").read()
    best = None
    for stanza in re.split(r"\n\s*\n", text):
        f = re.search(r"^Files:\s*(.+?)(?=^\S)", stanza + "\nX", re.M | re.S)
        lic = re.search(r"^License:\s*(\S+)", stanza, re.M)
        if not f or not lic:
            continue
        for g in f.group(1).split():
            if g == "*" or fnmatch.fnmatch(path, "*" + g) or os.path.basename(g) == os.path.basename(path):
                if g != "*" or best is None:
                    best = lic.group(1)
    return best or "see copyright"

def probe(path):
    out = subprocess.run(["ffprobe", "-v", "error", "-select_streams", "v", "-show_entries", "stream=width,height",
                          "-of", "csv=p=0", path], capture_output=True, text=True).stdout.strip().split(",")
    return int(out[0]), int(out[1])

def crop(path, out, scale_short, fx, fy, cw=384, ch=288):
    """A cw x ch crop at relative position (fx, fy) of the photo scaled to short side scale_short
    (0: native), area-averaged (no aliasing)."""
    if os.path.exists(out):
        return True
    w, h = probe(path)
    s = 1.0 if scale_short == 0 else scale_short / min(w, h)
    if s > 1.0:
        return False  # never upscale: it would invent no detail and teach blur as sharp
    sw, sh = int(w * s) // 2 * 2, int(h * s) // 2 * 2
    cw, ch = min(cw, sw), min(ch, sh)
    vf = f"scale={sw}:{sh}:flags=area,format=rgb24,crop={cw}:{ch}:{int((sw - cw) * fx)}:{int((sh - ch) * fy)}"
    subprocess.run(["ffmpeg", "-nostdin", "-v", "error", "-y", "-i", path, "-vf", vf, "-frames:v", "1", out], check=True)
    return True

rows = []
def scene(pkg, path, use, lic=None):
    lic = lic or licence(pkg, path)
    if lic == "see copyright":
        print(f"skipped (no licence stanza names it): {pkg} {path}", file=sys.stderr)
        return
    name = re.sub(r"[^A-Za-z0-9]+", "-", os.path.splitext(os.path.relpath(path, f"{src}/{pkg}"))[0].split("/usr/share/")[-1])[-60:].strip("-")
    w, h = probe(path)
    if use == "test":
        # One 256 x 256 crop at 720p scale (or native when smaller): the test clips.
        plan = [(720 if min(w, h) > 720 else 0, 0.5, 0.5, 256, 256)]
    elif min(w, h) <= 300:
        plan = [(0, 0.5, 0.5, 384, 288)]
    else:
        # Several scales: 720p (what the models meet in 720p footage), half of that (coarser
        # detail per pixel) and native (finer, when the photo is larger than 720p).
        plan = [(720, 0.2, 0.3, 384, 288), (720, 0.8, 0.7, 384, 288), (360, 0.5, 0.5, 384, 288), (0, 0.35, 0.6, 384, 288)]
    for i, (sc, fx, fy, cw, ch) in enumerate(plan):
        out = f"{data}/photos/{use}/{pkg}--{name}_{i}.png"
        if crop(path, out, sc, fx, fy, cw, ch):
            rows.append((os.path.relpath(out, data), pkg, version(pkg), lic, os.path.relpath(path, f"{src}/{pkg}"), use))

g = lambda pkg, pat: sorted(glob.glob(f"{src}/{pkg}/{pat}", recursive=True))
for f in g("mate-backgrounds", "usr/share/backgrounds/mate/nature/*.jpg"):
    scene("mate-backgrounds", f, "train")
for d in g("plasma-workspace-wallpapers", "usr/share/wallpapers/*/"):
    imgs = sorted(glob.glob(f"{d}contents/images/*"), key=os.path.getsize)
    if imgs:
        scene("plasma-workspace-wallpapers", imgs[-1], "train")
for pkg in ["lomiri-wallpapers", "lomiri-wallpapers-16.04"]:
    for f in g(pkg, "usr/share/backgrounds/**/*.*"):
        if f.lower().endswith((".jpg", ".png")):
            scene(pkg, f, "train")
for f in g("extremetuxracer-data", "usr/share/games/etr/terrains/*.png"):
    scene("extremetuxracer-data", f, "train")
# GCompris: the photographs of five activities, unpacked from their resource files.
for act in ["erase", "explore_monuments", "explore_world_animals", "explore_farm_animals", "explore_world_music"]:
    files = dict(rcc_files(f"{src}/gcompris-qt-data/usr/share/gcompris-qt/rcc/{act}.rcc"))
    for readme in [n for n in files if n.endswith("/README")]:
        folder = readme[: -len("README")]
        for rel, lic in sorted(readme_licences(files[readme].decode("utf-8", "replace")).items()):
            n = folder + rel
            if n not in files or not n.lower().endswith((".webp", ".jpg", ".png")):
                continue
            out = f"{src}/gcompris-qt-data/unpacked/{n}"
            if not os.path.exists(out):
                os.makedirs(os.path.dirname(out), exist_ok=True)
                open(out, "wb").write(files[n])
            if min(probe(out)) >= 400:  # icons and thumbnails are not scenes
                scene("gcompris-qt-data", out, "train", lic)
for f in g("tuxpaint-data", "usr/share/tuxpaint/templates/*.jpg"):
    scene("tuxpaint-data", f, "train")
for f in g("palapeli-data", "usr/share/palapeli/collection/*.jpg"):
    scene("palapeli-data", f, "train")
# LXQt: its photographs only (the rest are drawn: origami, triangles, logos).
for n in ["Butterfly-Kenneth-Wimer.jpg", "Valendas.png", "after-the-rain.jpg", "appleflower.png", "beam.png", "butterfly.png",
          "cloud.png", "drop.png", "flowers.png", "fog.jpg", "this-is-not-windows.jpg"]:
    for f in g("lxqt-themes", f"usr/share/lxqt/wallpapers/{n}"):
        scene("lxqt-themes", f, "train", "CC-BY-SA-3.0 (usr/share/lxqt/wallpapers/License)")
sk = "public domain / CC0 (skimage/data/README.txt)"
for n in ["astronaut.png", "chelsea.png", "coffee.png", "rocket.jpg", "motorcycle_left.png", "motorcycle_right.png", "grass.png",
          "gravel.png", "brick.png", "hubble_deep_field.jpg", "retina.jpg", "ihc.png", "camera.png", "moon.png", "coins.png"]:
    for f in g("python3-skimage", f"usr/lib/python3/dist-packages/skimage/data/{n}"):
        scene("python3-skimage", f, "train", sk)
# Objects: photographic stamps with alpha, copied as they are.
for f in g("tuxpaint-stamps-default", "usr/share/tuxpaint/stamps/**/*.png"):
    rel = os.path.relpath(f, f"{src}/tuxpaint-stamps-default/usr/share/tuxpaint/stamps")
    if re.search(r"(^|/)(cartoon|symbols|space)(/|$)", rel) or "-outline" in rel:
        continue
    out = f"{data}/objects/{rel.replace('/', '--')}"
    if not os.path.exists(out):
        # Expanded to RGBA (palette stamps carry their transparency in tRNS).
        subprocess.run(["ffmpeg", "-nostdin", "-v", "error", "-y", "-i", f, "-vf", "format=rgba", "-frames:v", "1", out], check=True)
    # A cut-out needs transparent pixels (some stamps are opaque photos): keep only those.
    alpha = subprocess.run(["ffmpeg", "-nostdin", "-v", "error", "-i", out, "-vf", "alphaextract,format=gray", "-f", "rawvideo", "-"],
                           capture_output=True).stdout
    if not alpha or min(alpha) == 255:
        os.remove(out)
        continue
    rows.append((os.path.relpath(out, data), "tuxpaint-stamps-default", version("tuxpaint-stamps-default"), licence("tuxpaint-stamps-default", f), rel, "object"))
for f in g("ukui-wallpapers", "usr/share/backgrounds/*.*"):
    scene("ukui-wallpapers", f, "test")
for f in g("lomiri-wallpapers-20.04", "usr/share/backgrounds/**/*.jpg"):
    scene("lomiri-wallpapers-20.04", f, "test")
for n in ["china.jpg", "flower.jpg"]:
    for f in g("python3-sklearn", f"usr/lib/python3/dist-packages/sklearn/datasets/images/{n}"):
        scene("python3-sklearn", f, "test", "CC-BY-2.0 (sklearn/datasets/images/README.txt)")
with open(f"{data}/photos/MANIFEST.tsv", "w") as m:
    m.write("file\tsource_package\tversion\tlicence\toriginal_path\tuse\n")
    for r in rows:
        m.write("\t".join(r) + "\n")
count = lambda u: len({r[4] + r[1] for r in rows if r[5] == u})
print(f"photos: {count('train')} training photographs ({sum(r[5] == 'train' for r in rows)} crops) from "
      f"{len({r[1] for r in rows if r[5] == 'train'})} packages, {count('object')} cut-outs, "
      f"{count('test')} test photographs -> {data}/photos/MANIFEST.tsv", file=sys.stderr)
PY
}

# Training shards: windows of N = 7, 9, 11 and 13 through each camera, the same clips, motions,
# noise and patches for both (the seed depends on N only).
# NS, PHOTOS and SET render an extra set beside these (the models' second round, models/README.md):
#   STEP=added bash scripts/training-data.sh     # photos/train-added: links to the crops of ADDED_PKGS
#   STEP=shards NS=9 PHOTOS=$DATA/photos/train-added SET=added SEED=200 bash scripts/training-data.sh
shards() {
  for n in ${NS:-7 9 11 13}; do
    for cam in phase_coded conventional; do
      d="$DATA/shards/$cam-n$n${SET:+-$SET}"
      [ -f "$d/manifest.json" ] && [ "${REDO:-0}" = 0 ] && continue
      "$PIPELINE" run pipelines/train-data.toml -o "$d" --set seed=$((${SEED:-11} + n)) --set transforms.blur.window=$n \
        --set sources.stills.frames=$((8 * n)) --set transforms.blur.camera.type=$cam --set sinks.shards.prefix=n$n${SET:+-$SET} \
        --set "sources.stills.paths=[\"${PHOTOS:-$DATA/photos/train}\"]" --set "sources.stills.motion.object_paths=[\"$DATA/objects\"]"
    done
  done
}

# Test clips: each test photograph moved by one named motion at a time (hand: hand-held shake to
# 60 px of spread, render/hand.rs), windows of 13 frames of
# one motion each (so the N = 7 to 13 windows that `pipeline eval` centres in them see the same
# motion, shorter), written as lossless video.
test_clips() {
  for kind in shake objects still pan rotate zoom hand; do
    test_clip "$DATA/test/$kind" "$kind" $((100 + ${#kind}))
  done
}

# More clips of the shakes (the same test photographs, other seeds: $DATA/test-more/{shake,hand},
# 72 clips each), for tables by spread with more than a few windows a bin.
test_more() {
  for kind in shake hand; do
    for s in 1 2 3 4; do test_clip "$DATA/test-more/$kind/s$s" "$kind" $((200 + 10 * s + ${#kind})); done
  done
}

# test_clip DIR KIND SEED: the test photographs moved by KIND alone, as lossless clips in DIR.
test_clip() {
  local d=$1 kind=$2 seed=$3 w="" k sharp clip
  [ -n "$(ls "$d"/*.mkv 2>/dev/null)" ] && return 0
  rm -rf "$d.frames"
  for k in shake objects still pan rotate zoom hand; do w="$w${w:+, }$k = $([ $k = "$kind" ] && echo 1.0 || echo 0.0)"; done
  "$PIPELINE" run pipelines/test-clips.toml -o "$d.frames" --set "sources.stills.paths=[\"$DATA/photos/test\"]" \
    --set "sources.stills.motion.weights={ $w }" --set seed="$seed"
  mkdir -p "$d"
  for sharp in "$d.frames"/*/sharp; do
    clip=$(basename "$(dirname "$sharp")")
    ffmpeg -nostdin -v error -y -framerate 240 -i "$sharp/%06d.png" -c:v ffv1 "$d/$clip.mkv"
    cp "$(dirname "$sharp")/motion.jsonl" "$d/$clip.motion.jsonl"   # the true motion, for eval's Wiener bound
  done
  rm -rf "$d.frames"
}

# The packages added in the second round (148 photographs, 480 crops).
ADDED_PKGS="gcompris-qt-data tuxpaint-data palapeli-data lxqt-themes"
added() {
  mkdir -p "$DATA/photos/train-added"
  awk -F'\t' -v pkgs="$ADDED_PKGS" 'BEGIN { n = split(pkgs, p, " "); for (i = 1; i <= n; i++) want[p[i]] = 1 }
    $6 == "train" && ($2 in want) { print $1 }' "$DATA/photos/MANIFEST.tsv" |
    while read -r f; do ln -sf "../train/$(basename "$f")" "$DATA/photos/train-added/$(basename "$f")"; done
  echo "added: $(ls "$DATA/photos/train-added" | wc -l) crops -> $DATA/photos/train-added" >&2
}

case $STEP in
  photos) photos ;;
  added) added ;;
  shards) shards ;;
  test) test_clips ;;
  test-more) test_more ;;
  all) photos; shards; test_clips ;;
esac
