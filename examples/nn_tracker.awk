# A tracker in another language: greedy nearest neighbour with an alpha-beta filter, in POSIX awk (gawk, mawk,
# busybox awk). It reads the detections of `testbed export RUN --format csv` and writes a tracks table that
# `testbed score` scores against the run's truth (docs/formats.md, "CSV"):
#
#   testbed export RUN --format csv                                  # RUN/csv/detections.csv, ...
#   awk -f examples/nn_tracker.awk RUN/csv/detections.csv > RUN/awk_tracks.csv
#   testbed score RUN --tracks RUN/awk_tracks.csv
#
# Input: the header names the columns; only frame, time, x, y [m] are read (provenance is the truth, for scoring
# only: a tracker must not read it; r_xx, r_xy, r_yy are there for a tracker that weighs its measurements).
# Output: frame, time, track_id, status (confirmed / tentative), x, y [m], vx, vy [m/s], every live track at
# every frame that has a detection.
BEGIN {
    FS = ","
    GATE = 3.0           # [m] a detection farther than this from every predicted track starts a new track
    ALPHA = 0.5; BETA = 0.3  # position and velocity gains
    CONFIRM = 3          # hits to confirm a track
    MAX_MISSES = 3       # frames without a detection before a track is dropped
    nt = 0; next_id = 1; m = 0; cur = ""; last = ""
    print "frame,time,track_id,status,x,y,vx,vy"
}
NR == 1 { for (i = 1; i <= NF; i++) col[$i] = i; next }
{
    if ($(col["frame"]) != cur && cur != "") step()
    cur = $(col["frame"]); now = $(col["time"])
    m++; zx[m] = $(col["x"]) + 0; zy[m] = $(col["y"]) + 0
}
END { if (cur != "") step() }

# One frame: predict, associate (closest pair first), update, start tracks, drop lost ones, print.
function step(    dt, i, j, d, best, bi, bj, k) {
    dt = (last == "") ? 0 : now - last
    last = now
    for (i = 1; i <= nt; i++) { tx[i] += dt * tvx[i]; ty[i] += dt * tvy[i]; hit[i] = 0 }
    for (j = 1; j <= m; j++) used[j] = 0
    while (1) {  # greedy: the closest free (track, detection) pair within the gate, until none is left
        best = GATE; bi = 0
        for (i = 1; i <= nt; i++) if (!hit[i]) for (j = 1; j <= m; j++) if (!used[j]) {
            d = sqrt((zx[j] - tx[i]) ^ 2 + (zy[j] - ty[i]) ^ 2)
            if (d < best) { best = d; bi = i; bj = j }
        }
        if (bi == 0) break
        hit[bi] = 1; used[bj] = 1
        rx = zx[bj] - tx[bi]; ry = zy[bj] - ty[bi]
        tx[bi] += ALPHA * rx; ty[bi] += ALPHA * ry
        if (dt > 0) { tvx[bi] += BETA * rx / dt; tvy[bi] += BETA * ry / dt }
    }
    k = 0  # keep the tracks still alive, in order
    for (i = 1; i <= nt; i++) {
        if (hit[i]) { hits[i]++; miss[i] = 0 } else miss[i]++
        if (miss[i] <= MAX_MISSES) {
            k++; tx[k] = tx[i]; ty[k] = ty[i]; tvx[k] = tvx[i]; tvy[k] = tvy[i]
            tid[k] = tid[i]; hits[k] = hits[i]; miss[k] = miss[i]
        }
    }
    nt = k
    for (j = 1; j <= m; j++) if (!used[j]) {
        nt++; tx[nt] = zx[j]; ty[nt] = zy[j]; tvx[nt] = 0; tvy[nt] = 0
        tid[nt] = next_id++; hits[nt] = 1; miss[nt] = 0
    }
    for (i = 1; i <= nt; i++)
        printf "%d,%.6f,%d,%s,%.4f,%.4f,%.4f,%.4f\n", cur, now, tid[i], \
            (hits[i] >= CONFIRM ? "confirmed" : "tentative"), tx[i], ty[i], tvx[i], tvy[i]
    m = 0
}
