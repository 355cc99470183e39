/* Closest-hit throughput of Embree 4 (rtcIntersect1, one ray at a time) on the rays
 * `meso bench rays MESH --save-rays DIR` writes, so the tracer and Embree are timed on
 * the same triangles and the same rays. Not part of the build: run.sh compiles it
 * against the Embree 4 library shipped in PyPI's `embreex` wheel (which has no
 * headers), so the few declarations it needs are written out below from Embree 4's
 * public API (rtcore_*.h).
 *
 * usage: embree_bench DIR THREADS [low|medium|high]
 * prints, per kind, the fastest of three traces in Mrays/s, the hit fraction, and how
 * many rays agree with the tracer's hit distances (DIR/<kind>_t.f32).
 */
#define _GNU_SOURCE
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

typedef struct RTCDeviceTy *RTCDevice;
typedef struct RTCSceneTy *RTCScene;
typedef struct RTCGeometryTy *RTCGeometry;

enum { RTC_GEOMETRY_TYPE_TRIANGLE = 0 };
enum { RTC_BUFFER_TYPE_INDEX = 0, RTC_BUFFER_TYPE_VERTEX = 1 };
enum { RTC_FORMAT_UINT3 = 0x5003, RTC_FORMAT_FLOAT3 = 0x9003 };
enum { RTC_BUILD_QUALITY_LOW = 0, RTC_BUILD_QUALITY_MEDIUM = 1, RTC_BUILD_QUALITY_HIGH = 2 };
enum { RTC_DEVICE_PROPERTY_VERSION = 0 };
#define RTC_INVALID_GEOMETRY_ID ((unsigned)-1)

struct __attribute__((aligned(16))) RTCRay {
  float org_x, org_y, org_z, tnear;
  float dir_x, dir_y, dir_z, time;
  float tfar;
  unsigned mask, id, flags;
};
/* Ng, u, v, primID, geomID, instID[1] and, where built with instance arrays,
 * instPrimID[1]: padded so that either layout fits. */
struct __attribute__((aligned(16))) RTCHit {
  float Ng_x, Ng_y, Ng_z, u, v;
  unsigned primID, geomID;
  unsigned inst[5];
};
struct __attribute__((aligned(16))) RTCRayHit {
  struct RTCRay ray;
  struct RTCHit hit;
};

RTCDevice rtcNewDevice(const char *config);
int rtcGetDeviceError(RTCDevice device);
long rtcGetDeviceProperty(RTCDevice device, int prop);
RTCScene rtcNewScene(RTCDevice device);
void rtcSetSceneBuildQuality(RTCScene scene, int quality);
RTCGeometry rtcNewGeometry(RTCDevice device, int type);
void *rtcSetNewGeometryBuffer(RTCGeometry g, int type, unsigned slot, int format,
                              size_t stride, size_t count);
void rtcCommitGeometry(RTCGeometry g);
unsigned rtcAttachGeometry(RTCScene scene, RTCGeometry g);
void rtcReleaseGeometry(RTCGeometry g);
void rtcCommitScene(RTCScene scene);
void rtcIntersect1(RTCScene scene, struct RTCRayHit *rayhit, void *args);

static float *read_floats(const char *dir, const char *name, size_t *count) {
  char path[4096];
  snprintf(path, sizeof path, "%s/%s", dir, name);
  FILE *f = fopen(path, "rb");
  if (!f) { fprintf(stderr, "cannot open %s\n", path); exit(2); }
  fseek(f, 0, SEEK_END);
  long bytes = ftell(f);
  fseek(f, 0, SEEK_SET);
  float *data = malloc(bytes ? bytes : 1);
  if (fread(data, 1, bytes, f) != (size_t)bytes) { fprintf(stderr, "short read %s\n", path); exit(2); }
  fclose(f);
  *count = bytes / sizeof(float);
  return data;
}

static double now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

struct job {
  RTCScene scene;
  const float *rays;
  float *t;
  size_t n;
  atomic_size_t next;
};

/* Rays are handed out in chunks, as rayon's work splitting does for the tracer. */
static void *worker(void *arg) {
  struct job *job = arg;
  const size_t chunk = 1024;
  for (;;) {
    size_t start = atomic_fetch_add(&job->next, chunk);
    if (start >= job->n) return NULL;
    size_t end = start + chunk < job->n ? start + chunk : job->n;
    for (size_t i = start; i < end; i++) {
      const float *r = job->rays + 6 * i;
      struct RTCRayHit rh;
      rh.ray.org_x = r[0]; rh.ray.org_y = r[1]; rh.ray.org_z = r[2];
      rh.ray.dir_x = r[3]; rh.ray.dir_y = r[4]; rh.ray.dir_z = r[5];
      rh.ray.tnear = 0.0f;
      rh.ray.tfar = INFINITY;
      rh.ray.time = 0.0f;
      rh.ray.mask = ~0u;
      rh.ray.id = 0;
      rh.ray.flags = 0;
      rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
      rh.hit.inst[0] = RTC_INVALID_GEOMETRY_ID;
      rtcIntersect1(job->scene, &rh, NULL);
      job->t[i] = rh.hit.geomID == RTC_INVALID_GEOMETRY_ID ? INFINITY : rh.ray.tfar;
    }
  }
}

int main(int argc, char **argv) {
  if (argc < 3) { fprintf(stderr, "usage: %s DIR THREADS [low|medium|high]\n", argv[0]); return 2; }
  const char *dir = argv[1];
  int threads = atoi(argv[2]);
  if (threads < 1 || threads > 256) { fprintf(stderr, "THREADS must be in [1, 256]\n"); return 2; }
  int quality = RTC_BUILD_QUALITY_MEDIUM;
  const char *quality_name = argc > 3 ? argv[3] : "medium";
  if (!strcmp(quality_name, "low")) quality = RTC_BUILD_QUALITY_LOW;
  else if (!strcmp(quality_name, "high")) quality = RTC_BUILD_QUALITY_HIGH;
  else if (strcmp(quality_name, "medium")) { fprintf(stderr, "quality: low, medium or high\n"); return 2; }

  char config[64];
  snprintf(config, sizeof config, "threads=%d", threads);
  RTCDevice device = rtcNewDevice(config);
  if (!device) { fprintf(stderr, "rtcNewDevice failed: %d\n", rtcGetDeviceError(NULL)); return 1; }
  size_t nf;
  float *tris = read_floats(dir, "triangles.f32", &nf);
  size_t ntri = nf / 9;
  RTCScene scene = rtcNewScene(device);
  rtcSetSceneBuildQuality(scene, quality);
  RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
  float *vb = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                      3 * sizeof(float), 3 * ntri);
  unsigned *ib = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                         3 * sizeof(unsigned), ntri);
  memcpy(vb, tris, 9 * ntri * sizeof(float));
  for (size_t i = 0; i < 3 * ntri; i++) ib[i] = (unsigned)i;
  rtcCommitGeometry(geom);
  rtcAttachGeometry(scene, geom);
  rtcReleaseGeometry(geom);
  double t0 = now();
  rtcCommitScene(scene);
  double build_ms = 1e3 * (now() - t0);
  if (rtcGetDeviceError(device)) { fprintf(stderr, "Embree error %d\n", rtcGetDeviceError(device)); return 1; }
  long version = rtcGetDeviceProperty(device, RTC_DEVICE_PROPERTY_VERSION);
  printf("Embree %ld.%ld.%ld, %zu triangles, %s build quality, built in %.1f ms, %d thread(s)\n",
         version / 10000, version / 100 % 100, version % 100, ntri, quality_name, build_ms, threads);

  const char *kinds[2] = {"coherent", "incoherent"};
  for (int k = 0; k < 2; k++) {
    char name[64];
    snprintf(name, sizeof name, "%s.f32", kinds[k]);
    size_t nr;
    float *rays = read_floats(dir, name, &nr);
    size_t n = nr / 6;
    snprintf(name, sizeof name, "%s_t.f32", kinds[k]);
    size_t nt;
    float *ours = read_floats(dir, name, &nt);
    if (nt != n) { fprintf(stderr, "%s: %zu distances for %zu rays\n", name, nt, n); return 2; }
    float *t = malloc(n * sizeof(float));
    double best = INFINITY;
    for (int run = 0; run < 3; run++) {
      struct job job = {scene, rays, t, n, 0};
      pthread_t ids[256];
      double start = now();
      for (int i = 1; i < threads; i++) pthread_create(&ids[i], NULL, worker, &job);
      worker(&job);
      for (int i = 1; i < threads; i++) pthread_join(ids[i], NULL);
      double s = now() - start;
      if (s < best) best = s;
    }
    size_t hits = 0, agree = 0;
    for (size_t i = 0; i < n; i++) {
      hits += isfinite(t[i]);
      /* Same answer: both miss, or both hit within a relative 1e-4 (Embree's
       * triangle test is not Moller-Trumbore; silhouette rays may differ). */
      if (!isfinite(t[i]) && !isfinite(ours[i])) agree++;
      else if (isfinite(t[i]) && isfinite(ours[i]) && fabsf(t[i] - ours[i]) <= 1e-4f * ours[i]) agree++;
    }
    printf("%s: %zu rays, %.2f Mrays/s (%.1f%% hit), %.4f%% agree with the tracer's hits\n",
           kinds[k], n, n / best / 1e6, 100.0 * hits / n, 100.0 * agree / n);
    free(rays);
    free(ours);
    free(t);
  }
  return 0;
}
