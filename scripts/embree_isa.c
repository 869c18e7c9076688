/* Preloaded into embree_bench by scripts/bench-vs-embree.sh when EMBREE_ISA is
 * set (e.g. EMBREE_ISA=avx2): appends ",isa=$EMBREE_ISA" to the configuration
 * of every Embree device, so Embree runs the kernels of that instruction set
 * instead of the best one the CPU has. Issue 6's reference figures come from
 * an AVX2 machine without AVX-512; on a CPU with AVX-512 this measures the
 * Embree those figures describe, next to the native one. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>

typedef void *(*new_device_fn)(const char *config);

void *rtcNewDevice(const char *config) {
  new_device_fn real = (new_device_fn)dlsym(RTLD_NEXT, "rtcNewDevice");
  const char *isa = getenv("EMBREE_ISA");
  if (!real) return NULL;
  if (!isa || !*isa) return real(config);
  char buf[512];
  snprintf(buf, sizeof buf, "%s%sisa=%s", config ? config : "", config && *config ? "," : "", isa);
  return real(buf);
}
