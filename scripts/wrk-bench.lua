-- wrk script for scripts/load-test.sh.
--
-- With WRK_BODY_FILE set, every request is a POST of that file's bytes with Content-Type
-- WRK_CONTENT_TYPE (default application/json); otherwise wrk's default GET. The request is built
-- once per thread at load time (wrk's static request path), so the client adds no per-request Lua.
--
-- At the end it prints one machine-readable line:
--   RESULT requests=N seconds=S rps=R p50_ms=… p90_ms=… p99_ms=… max_ms=… errors=E non2xx=M
-- (wrk's own summary counts any status >= 400 as "Non-2xx or 3xx"; a 304 is a success here.)

local body_file = os.getenv("WRK_BODY_FILE")
if body_file and body_file ~= "" then
   local f = assert(io.open(body_file, "rb"))
   wrk.method = "POST"
   wrk.body = f:read("*a")
   f:close()
   wrk.headers["Content-Type"] = os.getenv("WRK_CONTENT_TYPE") or "application/json"
end

function done(summary, latency, requests)
   local secs = summary.duration / 1e6
   local e = summary.errors
   io.write(string.format(
      "RESULT requests=%d seconds=%.2f rps=%.0f p50_ms=%.3f p90_ms=%.3f p99_ms=%.3f max_ms=%.3f errors=%d non2xx=%d\n",
      summary.requests, secs, summary.requests / secs,
      latency:percentile(50) / 1000, latency:percentile(90) / 1000,
      latency:percentile(99) / 1000, latency.max / 1000,
      e.connect + e.read + e.write + e.timeout, e.status))
end
